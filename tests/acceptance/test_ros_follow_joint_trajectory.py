"""The arm (config/arm6.yaml) driven through ``control_msgs/action/FollowJointTrajectory`` as
MoveIt's simple controller manager drives a JointTrajectoryController: the simulator and the
node run as their own processes on the two ends of a veth pair; this process is a separate
rclpy action client with a ROS domain of its own. Nothing is faked.

Covers: a goal for all six joints succeeds with feedback (desired, actual, error) at 50 Hz or
more; a path tolerance and a goal tolerance violated give their result codes and leave the arm
standing without a fault; a cancel and a preemption stop the running goal smoothly (the axes'
position targets, read back as the feedback's desired positions, never jump); bad goals are
refused with the standard code and a message, and nothing moves; a goal whose joint leaves it
(another mode, disabled, a fault, a panic) ends aborted with the reason, and its other joint
stops. Timing is never asserted beyond the feedback's rate over a whole goal.
"""

from __future__ import annotations

import itertools
import math
import time
from collections.abc import Iterator

import pytest

from arm_ros import JOINTS, enabled_arm_rig, positions, settled, stamped_positions
from ether_ros.ros.client import EtherRosClient
from ether_ros.ros.rig import RosRig
from ether_ros.ros.trajectory_client import Result, TrajectoryActionClient, make_goal

pytestmark = [pytest.mark.netns, pytest.mark.ros, pytest.mark.slow]

SUCCEEDED, CANCELED, ABORTED = 4, 5, 6
# The joints' largest velocity limit (rad/s, arm6): a desired position that moves faster jumped.
MAX_SPEED = 4.0 * 1.05


@pytest.fixture(scope="module")
def rig(veth_allowed: bool) -> Iterator[RosRig]:
    yield from enabled_arm_rig(veth_allowed)


@pytest.fixture(scope="module")
def fjt(rig: RosRig) -> TrajectoryActionClient:
    return TrajectoryActionClient(rig.client.node)


def home(fjt: TrajectoryActionClient, client: EtherRosClient) -> dict[str, float]:
    """All joints to 0 (a goal that must succeed); the positions afterwards."""
    here = positions(client)
    far = max(abs(p) for p in here.values())
    outcome = fjt.run(JOINTS, [(max(far / 0.5, 0.5), [0.0] * 6)])
    assert outcome.status == SUCCEEDED, outcome
    return settled(client)


def desired_speed(outcome: object) -> float:
    """The fastest any joint's desired position moved between two feedback messages (by their
    time_from_start, engine clock): a jump shows as a speed far beyond the velocity limit."""
    fb = [f for _, f in outcome.feedback]  # type: ignore[attr-defined]

    def t(f: object) -> float:
        d = f.desired.time_from_start  # type: ignore[attr-defined]
        return float(d.sec) + float(d.nanosec) * 1e-9

    speeds = (
        abs(q - p) / max(t(b) - t(a), 1e-3)
        for a, b in itertools.pairwise(fb)
        for p, q in zip(a.desired.positions, b.desired.positions, strict=True)
    )
    return max(speeds, default=0.0)


def test_a_goal_for_every_joint_succeeds_with_feedback(
    rig: RosRig, fjt: TrajectoryActionClient
) -> None:
    client = rig.client
    home(fjt, client)
    targets = [0.3, -0.2, 0.4, -0.3, 0.2, -0.4]
    outcome = fjt.run(
        JOINTS,
        [(0.6, [t / 2 for t in targets]), (1.2, targets)],
        goal_tolerance=dict.fromkeys(JOINTS, 0.005),
        path_tolerance=dict.fromkeys(JOINTS, 0.05),
    )
    assert (outcome.status, outcome.error_code) == (SUCCEEDED, Result.SUCCESSFUL), outcome
    now = settled(client)
    assert all(abs(now[j] - t) < 0.005 for j, t in zip(JOINTS, targets, strict=True)), now
    # Feedback all along the goal (its rate is measured in the benchmark, bench_trajectory).
    fb = outcome.feedback
    assert len(fb) > 10

    def t(f: object) -> float:
        d = f.desired.time_from_start  # type: ignore[attr-defined]
        return float(d.sec) + float(d.nanosec) * 1e-9

    # From the start into the second segment. Not up to the end: rclpy's action client drops
    # feedback it takes together with or after the result, so the last ones may never show.
    assert t(fb[0][1]) < 0.3 and t(fb[-1][1]) > 0.6, (t(fb[0][1]), t(fb[-1][1]))
    assert all(t(b) >= t(a) for (_, a), (_, b) in itertools.pairwise(fb))
    last = fb[-1][1]
    assert list(last.joint_names) == JOINTS
    for d, a, e in zip(last.desired.positions, last.actual.positions, last.error.positions,
                       strict=True):  # fmt: skip
        assert math.isclose(e, d - a, abs_tol=1e-12)
    assert desired_speed(outcome) < MAX_SPEED


def test_a_violated_path_tolerance_aborts_and_stops_the_joints(
    rig: RosRig, fjt: TrajectoryActionClient
) -> None:
    client = rig.client
    home(fjt, client)
    # 0.6 rad in 0.3 s: the drives follow a few mrad behind, beyond 0.1 mrad.
    outcome = fjt.run(["elbow"], [(0.3, [0.6])], path_tolerance={"elbow": 1e-4})
    assert (outcome.status, outcome.error_code) == (ABORTED, Result.PATH_TOLERANCE_VIOLATED)
    assert "joint 'elbow': position error" in outcome.error_string, outcome.error_string
    assert "path tolerance 0.0001" in outcome.error_string
    # A quiet stop, short of the target, no fault: the arm stands and takes the next goal.
    stopped = settled(client)["elbow"]
    assert 0.0 < stopped < 0.55, stopped
    home(fjt, client)


def test_a_violated_goal_tolerance_aborts(rig: RosRig, fjt: TrajectoryActionClient) -> None:
    client = rig.client
    home(fjt, client)
    # A final position half an encoder count off the grid: the drive settles on a count, so it
    # never comes within 1 µrad, whatever the timing.
    scale = 7.66990394e-6
    final = (round(0.3 / scale) + 0.5) * scale
    outcome = fjt.run(["elbow"], [(0.5, [final])], goal_tolerance={"elbow": 1e-6},
                      goal_time_tolerance=0.3)  # fmt: skip
    assert (outcome.status, outcome.error_code) == (ABORTED, Result.GOAL_TOLERANCE_VIOLATED)
    assert "goal tolerance 1e-06" in outcome.error_string, outcome.error_string
    assert "0.3 s after the trajectory's end" in outcome.error_string
    home(fjt, client)


def test_a_cancel_stops_the_joint_smoothly(rig: RosRig, fjt: TrajectoryActionClient) -> None:
    client = rig.client
    home(fjt, client)
    # A slow goal (0.17 rad/s): a cancel that a loaded host answers seconds late still stops
    # the joint well short of its target.
    run = fjt.send(make_goal(["wrist_2"], [(6.0, [1.0])]))
    deadline = time.monotonic() + 10
    while positions(client)["wrist_2"] < 0.2:
        assert time.monotonic() < deadline, "the goal did not start"
        time.sleep(0.01)
    run.cancel()
    outcome = run.wait()
    assert (outcome.status, outcome.error_code) == (CANCELED, Result.SUCCESSFUL), outcome
    stopped = settled(client)["wrist_2"]
    assert 0.2 < stopped < 0.95, stopped
    assert desired_speed(outcome) < MAX_SPEED
    home(fjt, client)


def test_a_new_goal_preempts_the_running_one_without_a_jump(
    rig: RosRig, fjt: TrajectoryActionClient
) -> None:
    client = rig.client
    home(fjt, client)
    # A long first goal: the second must reach the server before it ends (a loaded host took
    # longer than the rest of a 2 s goal).
    first = fjt.send(make_goal(["elbow", "wrist_1"], [(8.0, [1.0, -1.0])]))
    deadline = time.monotonic() + 20
    while positions(client)["elbow"] < 0.2:
        assert time.monotonic() < deadline, "the goal did not start"
        time.sleep(0.01)
    second = fjt.send(make_goal(["elbow", "wrist_1"], [(1.0, [0.1, -0.1])]))
    old = first.wait()
    assert (old.status, old.error_code) == (ABORTED, Result.INVALID_GOAL), old
    assert "replaced by a newer goal" in old.error_string
    new = second.wait()
    assert (new.status, new.error_code) == (SUCCEEDED, Result.SUCCESSFUL), new
    assert desired_speed(new) < MAX_SPEED
    now = settled(client)
    assert abs(now["elbow"] - 0.1) < 0.01 and abs(now["wrist_1"] + 0.1) < 0.01, now


@pytest.mark.parametrize(
    ("event", "reason"),
    [
        ("set_mode", "joint 'wrist_1' left csp (now csv)"),
        ("disable", "joint 'wrist_1' disabled"),
        ("fault", "joint 'wrist_1' fault 0x7305 (incremental encoder 1 fault)"),
        ("panic", "panic (joint 'elbow' stopped)"),
    ],
)
def test_a_goal_whose_joint_leaves_it_aborts_with_the_reason(
    rig: RosRig, fjt: TrajectoryActionClient, event: str, reason: str
) -> None:
    """Issue 24: a goal whose joint is switched to another mode, disabled, faulted, or
    panicked ends aborted (INVALID_JOINTS) with the joint and what happened, and the goal's
    other joint makes a quiet stop instead of going on alone. The goal lasts 12 s: its result
    within the wait, with the elbow standing far short of its target, proves it ended early
    (no timing is asserted)."""
    client = rig.client
    home(fjt, client)
    run = fjt.send(make_goal(["elbow", "wrist_1"], [(12.0, [1.0, -1.0])]))
    deadline = time.monotonic() + 30
    # The goal runs: its own feedback shows the elbow on its way.
    while not (run.outcome.feedback and run.outcome.feedback[-1][1].actual.positions[0] > 0.01):
        assert time.monotonic() < deadline, f"the goal did not start: {run.outcome}"
        time.sleep(0.01)
    try:
        if event == "set_mode":
            ok, message, _ = client.set_mode("csv", ["wrist_1"])
            assert ok, message
        elif event == "disable":
            ok, message, _ = client.axis_command("disable", ["wrist_1"])
            assert ok, message
        elif event == "fault":
            rig.sim("fault", kind="drive_fault", slave=1, axis=2, error="encoder")  # wrist_1
        else:
            ok, message = client.panic()
            assert ok, message
        outcome = run.wait(timeout=8)
        assert (outcome.status, outcome.error_code) == (ABORTED, Result.INVALID_JOINTS), outcome
        assert outcome.error_string.startswith(reason), outcome.error_string
        if event != "panic":  # the elbow's own stop is the engine's quiet stop: no jump
            assert desired_speed(outcome) < MAX_SPEED
        # Where the elbow stands a second after the end (its stop takes milliseconds), from a
        # joint_states stamped then: on a loaded host the topic may lag the action's result.
        _, after = stamped_positions(client, time.time() + 1.0)
        stopped = after["elbow"]
        assert 0.0 < stopped < 0.8, stopped
    finally:
        if event == "panic":
            ok, message = client.command("clear_panic")
            assert ok, message
        ok, message, _ = client.set_mode("csp", ["wrist_1"])
        assert ok, message
        if event == "fault":  # reset automatically (fault_reset: auto), waits for an enable
            client.wait_for(
                lambda _l: client.axis_states().get("wrist_1", {}).get("state") != "fault",
                timeout=10,
            )
        ok, message, _ = client.axis_command("enable")
        assert ok, message
    home(fjt, client)


@pytest.mark.parametrize(
    ("names", "points", "kwargs", "code", "why"),
    [
        (["nope"], [(0.5, [0.1])], {}, Result.INVALID_JOINTS, "unknown joint(s) 'nope'"),
        (["elbow", "elbow"], [(0.5, [0.1, 0.1])], {}, Result.INVALID_JOINTS, "twice"),
        ([], [(0.5, [])], {}, Result.INVALID_JOINTS, "names no joint"),
        (["elbow"], [(0.5, [0.1]), (0.5, [0.2])], {}, Result.INVALID_GOAL,
         "not after the previous"),
        (["elbow"], [(0.5, [math.nan])], {}, Result.INVALID_GOAL, "not finite"),
        (["elbow"], [(0.5, [math.inf])], {}, Result.INVALID_GOAL, "not finite"),
        (["elbow"], [(0.5, [5.0])], {}, Result.INVALID_GOAL, "outside the limits"),
        (["elbow"], [(0.1, [2.0])], {}, Result.INVALID_GOAL, "beyond the velocity limit"),
        (["elbow"], [(0.5, [0.1])], {"velocities": [[9.0]]}, Result.INVALID_GOAL,
         "velocity 9 is beyond"),
        (["elbow"], [(0.5, [0.1])], {"start": 1.0}, Result.OLD_HEADER_TIMESTAMP,
         "ended"),
        (["elbow"], [(0.5, [0.1])], {"path_tolerance": {"wrist_3": 0.1}},
         Result.INVALID_GOAL, "does not name"),
    ],
)  # fmt: skip
def test_bad_goals_are_refused_with_their_code_and_nothing_moves(
    rig: RosRig,
    fjt: TrajectoryActionClient,
    names: list[str],
    points: list[tuple[float, list[float]]],
    kwargs: dict[str, object],
    code: int,
    why: str,
) -> None:
    client = rig.client
    before = settled(client)
    outcome = fjt.run(names, points, **kwargs)  # type: ignore[arg-type]
    assert (outcome.status, outcome.error_code) == (ABORTED, code), outcome
    assert why in outcome.error_string, outcome.error_string
    after = settled(client)
    assert all(abs(after[j] - before[j]) < 1e-3 for j in JOINTS), (before, after)


def test_command_timeout_stops_neither_a_trajectory_nor_a_holding_arm(
    rig: RosRig, fjt: TrajectoryActionClient
) -> None:
    """command_timeout_ms stops feeding the watchdog only when something needs a live
    commander: a 1.5 s goal under a 300 ms timeout runs to its end and the arm then holds its
    position enabled; a velocity command left running is stopped by it."""
    client = rig.client
    home(fjt, client)
    ok, reason = client.set_parameter("command_timeout_ms", 300)
    assert ok, reason
    try:
        outcome = fjt.run(["elbow", "wrist_2"], [(1.5, [0.5, -0.5])])
        assert (outcome.status, outcome.error_code) == (SUCCEEDED, Result.SUCCESSFUL), outcome
        time.sleep(1.0)  # holding, nobody commanding
        assert client.master_status().get("ros_watchdog_active") == "0"
        states = client.axis_states()
        assert all(s["state"] == "operation_enabled" for s in states.values()), states
        # A velocity command and then silence: that needs a commander; the watchdog stops it.
        ok, message, _ = client.set_mode("csv", ["wrist_3"])
        assert ok, message
        client.publish_joint_command(["wrist_3"], velocity=[0.1])
        client.wait_for(lambda _l: client.master_status().get("ros_watchdog_active") == "1",
                        timeout=10)  # fmt: skip
        client.wait_for(
            lambda _l: client.axis_states().get("wrist_3", {}).get("state") != "operation_enabled",
            timeout=10,
        )
    finally:
        assert client.set_parameter("command_timeout_ms", 0)[0]
    ok, message, _ = client.axis_command("enable")
    assert ok, message
    ok, message, _ = client.set_mode("csp", ["wrist_3"])
    assert ok, message
