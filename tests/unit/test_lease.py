"""The control lease's policy (ether_ros.ros.lease) on the real native gate the command paths
check: who may command, take-over, renewal, lapse and release stopping motion, and bad requests
answered with a reason. A clock of the test's own drives time, so nothing here waits."""

from __future__ import annotations

import math

import pytest

from ether_ros.ros.lease import REFRESH_S, ControlLease, LeaseRefused

GID_A = bytes(range(16))
GID_B = bytes(range(16, 32))
GID_C = bytes(range(32, 48))


class Clock:
    def __init__(self) -> None:
        self.ns = 1_000_000_000

    def __call__(self) -> int:
        return self.ns

    def advance(self, seconds: float) -> None:
        self.ns += int(seconds * 1e9)


@pytest.fixture
def clock() -> Clock:
    return Clock()


def lease(
    clock: Clock, enabled: bool = True, stops: list[str] | None = None, writers: dict | None = None
) -> ControlLease:
    found = writers if writers is not None else {}
    return ControlLease(
        enabled,
        2.0,
        10.0,
        stop_motion=(stops if stops is not None else []).append,
        lookup_writers=lambda nodes: [g for n in nodes for g in found.get(n, [])],
        now_ns=clock,
    )


def acquire(lease_: ControlLease, holder: str, gids: bytes = b"", op: str = "acquire") -> int:
    answer = lease_.request(op, holder, 0.0, 0, gids, [])
    assert answer.success, answer.message
    assert answer.holder == holder and answer.token and answer.ttl_s == 2.0
    return answer.token


def test_off_lets_everyone_command(clock: Clock) -> None:
    off = lease(clock, enabled=False)
    off.check_token(0)
    off.check_publisher(None)
    off.check_publisher(GID_C)
    answer = off.request("acquire", "/x", 0.0, 0, b"", [])
    assert not answer.success and not answer.enabled and "off" in answer.message
    assert off.request("status", "", 0.0, 0, b"", []).success


def test_only_the_holder_commands_and_refusals_name_it(clock: Clock) -> None:
    lease_ = lease(clock)
    with pytest.raises(LeaseRefused, match="acquire it with the 'lease' service"):
        lease_.check_token(0)
    token = acquire(lease_, "/console", GID_A + GID_B)
    lease_.check_token(token)
    lease_.check_publisher(GID_A)
    lease_.check_publisher(GID_B)
    for bad in (lambda: lease_.check_token(token + 1), lambda: lease_.check_publisher(GID_C)):
        with pytest.raises(LeaseRefused, match="held by '/console'"):
            bad()
    with pytest.raises(LeaseRefused, match="native command path"):
        lease_.check_publisher(None)  # a message rclpy took: its publisher is unknown
    # A second client cannot acquire while it is held: it is told by whom.
    answer = lease_.request("acquire", "/rig", 0.0, 0, b"", [])
    assert not answer.success and "held by '/console'" in answer.message
    status = lease_.request("status", "", 0.0, 0, b"", [])
    assert status.success and status.holder == "/console" and not status.token
    assert lease_.status()["refused"] >= 3


def test_takeover_moves_the_lease_and_the_old_holder_is_refused(clock: Clock) -> None:
    lease_ = lease(clock)
    old = acquire(lease_, "/rig", GID_A)
    new = acquire(lease_, "/console", GID_B, op="takeover")
    assert new != old
    lease_.check_token(new)
    lease_.check_publisher(GID_B)
    with pytest.raises(LeaseRefused, match="held by '/console'"):
        lease_.check_token(old)
    with pytest.raises(LeaseRefused, match="held by '/console'"):
        lease_.check_publisher(GID_A)
    renew = lease_.request("renew", "/rig", 0.0, old, b"", [])
    assert not renew.success and "/console" in renew.message
    assert lease_.status()["taken_over"] == 1


def test_a_lapsed_lease_stops_motion_once(clock: Clock) -> None:
    stops: list[str] = []
    lease_ = lease(clock, stops=stops)
    token = acquire(lease_, "/rig", GID_A)
    clock.advance(1.5)
    assert lease_.request("renew", "/rig", 0.0, token, b"", []).success
    clock.advance(1.5)  # 3 s after the grant, 1.5 s after the renewal: still held
    lease_.poll()
    assert not stops
    lease_.check_token(token)
    clock.advance(0.6)
    # The gate refuses by itself the instant the lease runs out, before the watcher runs.
    with pytest.raises(LeaseRefused, match="lease of '/rig' lapsed"):
        lease_.check_publisher(GID_A)
    lease_.poll()
    lease_.poll()
    assert stops == ["the control lease of '/rig' lapsed"]
    with pytest.raises(LeaseRefused, match="lapsed"):
        lease_.check_token(token)
    assert not lease_.request("renew", "/rig", 0.0, token, b"", []).success
    assert lease_.status()["lapsed"] == 1 and lease_.holder() == ""
    acquire(lease_, "/rig")  # and anyone may acquire it again


def test_release_needs_the_token_and_hands_control_back(clock: Clock) -> None:
    stops: list[str] = []
    lease_ = lease(clock, stops=stops)
    token = acquire(lease_, "/rig")
    answer = lease_.request("release", "/other", 0.0, token + 1, b"", [])
    assert not answer.success
    assert lease_.request("release", "/rig", 0.0, token, b"", []).success
    assert not stops  # a deliberate hand-back leaves the outputs as they are
    with pytest.raises(LeaseRefused, match="lapsed"):
        lease_.check_token(token)
    clock.advance(10.0)
    lease_.poll()
    assert not stops  # and nothing lapses later
    assert lease_.status()["released"] == 1


def test_writer_nodes_are_looked_up_and_refreshed(clock: Clock) -> None:
    writers: dict[str, list[bytes]] = {"/controller": []}
    lease_ = lease(clock, writers=writers)
    answer = lease_.request("acquire", "/rig", 0.0, 0, b"", ["/controller"])
    assert answer.success
    with pytest.raises(LeaseRefused):
        lease_.check_publisher(GID_C)  # not discovered yet
    writers["/controller"] = [GID_C]  # discovery catches up
    clock.advance(REFRESH_S)
    lease_.poll()
    lease_.check_publisher(GID_C)


def test_an_action_goal_is_the_holders_when_its_client_is(clock: Clock) -> None:
    writers: dict[str, list[bytes]] = {"/move_group": []}
    lease_ = lease(clock, writers=writers)
    answer = lease_.request("acquire", "/rig", 0.0, 0, GID_A, ["/move_group"])
    assert answer.success
    lease_.check_goal_sender(GID_A)  # a registered client
    with pytest.raises(LeaseRefused, match="held by '/rig'"):
        lease_.check_goal_sender(GID_B)
    # A client the holder's node made since the last look is looked up before a refusal.
    writers["/move_group"] = [GID_C]
    lease_.check_goal_sender(GID_C)
    with pytest.raises(LeaseRefused, match="cannot tell who sent this goal"):
        lease_.check_goal_sender(None)
    lease(clock, enabled=False).check_goal_sender(None)  # lease off: anyone


@pytest.mark.parametrize(
    ("operation", "holder", "ttl", "gids", "nodes", "reason"),
    [
        ("grab", "/x", 0.0, b"", [], "unknown operation 'grab'"),
        ("acquire", "", 0.0, b"", [], "holder: give a name"),
        ("acquire", "/x\x00y", 0.0, b"", [], "no control characters"),
        ("acquire", "/x", math.nan, b"", [], "ttl_s must be a number"),
        ("acquire", "/x", -1.0, b"", [], "ttl_s must be a number"),
        ("acquire", "/x", 0.0, b"\x01" * 17, [], "whole number of 16-byte GIDs"),
        ("acquire", "/x", 0.0, b"\x01" * 16 * 33, [], "at most 32 publishers"),
        ("acquire", "/x", 0.0, b"", ["controller"], "not a full node name"),
        ("renew", "/x", 0.0, b"", [], "nobody holds the control lease"),
    ],
)
def test_bad_requests_are_answered_with_the_reason(
    clock: Clock,
    operation: str,
    holder: str,
    ttl: float,
    gids: bytes,
    nodes: list[str],
    reason: str,
) -> None:
    answer = lease(clock).request(operation, holder, ttl, 0, gids, nodes)
    assert not answer.success and reason in answer.message and not answer.token


def test_ttl_is_capped(clock: Clock) -> None:
    lease_ = lease(clock)
    answer = lease_.request("acquire", "/x", 1e9, 0, b"", [])
    assert answer.success and answer.ttl_s == 10.0
