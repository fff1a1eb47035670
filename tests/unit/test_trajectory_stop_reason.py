"""Issue 24 ("every goal ends"): the check that tells, from an axis's status, why a trajectory
cannot go on -- the reason a FollowJointTrajectory goal, a joint_trajectory and ``bus.follow``
end with. Pure functions on status dicts; the engine's part (the other axes stop quietly, the
``trajectory_stopped`` flag) is tested in crates/engine/src/cia402.rs, the whole path in
tests/unit/test_master_axis.py, tests/unit/test_ros_joints_inprocess.py and
tests/acceptance/test_ros_follow_joint_trajectory.py."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import pytest

from ether_ros.master.axis import stopped_with_trajectory, trajectory_stop_reason
from ether_ros.ros import bridge, joints


def status(**changes: Any) -> dict[str, Any]:
    """An axis running its trajectory in Operation Enabled, with ``changes``."""
    st: dict[str, Any] = {
        "state": "operation_enabled",
        "halted": False,
        "enable_wanted": True,
        "mode_reached": True,
        "mode_display": "csp",
        "error_code": 0,
        "last_fault_code": 0,
        "faults": 2,
        "trajectory_stopped": False,
        "trajectory_done": False,
        "trajectory_active": True,
        "command_seq": 7,
    }
    st.update(changes)
    return st


@pytest.mark.parametrize(
    ("changes", "current_mode", "panicked", "reason"),
    [
        ({}, "csp", False, None),
        # The joint was switched to another mode (the engine ended its trajectory).
        ({}, "pv", False, "joint 'elbow' left csp (now pv)"),
        ({"enable_wanted": False, "state": "quick_stop_active"}, "csp", False,
         "joint 'elbow' disabled"),
        ({"state": "fault", "error_code": 0x7305, "enable_wanted": True}, "csp", False,
         "joint 'elbow' fault 0x7305 (incremental encoder 1 fault)"),
        ({"state": "fault_reaction_active", "error_code": 0x2310}, "csp", False,
         "joint 'elbow' fault 0x2310"),
        # Reset automatically already (fault_reset: auto): the fault count says it happened.
        ({"state": "switch_on_disabled", "faults": 3, "last_fault_code": 0x7305}, "csp", False,
         "joint 'elbow' fault 0x7305"),
        ({"state": "quick_stop_active"}, "csp", False, "joint 'elbow' quick stop"),
        ({"halted": True, "state": "quick_stop_active"}, "csp", True,
         "panic (joint 'elbow' stopped)"),
        ({"halted": True}, "csp", False, "watchdog stop (joint 'elbow'"),
        ({"state": "switched_on"}, "csp", False,
         "joint 'elbow' left operation_enabled (now switched_on)"),
        ({"mode_reached": False, "mode_display": "csv"}, "csp", False,
         "joint 'elbow' left csp (the drive shows csv)"),
        # The flag alone is not the axis's own reason (see stopped_with_trajectory).
        ({"trajectory_stopped": True}, "csp", False, None),
    ],
)  # fmt: skip
def test_the_reason_names_the_joint_and_what_happened(
    changes: dict[str, Any], current_mode: str, panicked: bool, reason: str | None
) -> None:
    why = trajectory_stop_reason("elbow", "csp", current_mode, status(**changes), panicked, 2)
    if reason is None:
        assert why is None
    else:
        assert why is not None and why.startswith(reason), why


def test_a_panic_is_named_before_what_it_did_to_the_drive() -> None:
    # A panic halts a faulted, disabled axis in another mode too: the panic is the cause.
    st = status(halted=True, state="fault", error_code=0x7305, enable_wanted=False)
    why = trajectory_stop_reason("elbow", "csp", "csv", st, True)
    assert why == "panic (joint 'elbow' stopped)"
    # Without a baseline an old fault count is no reason.
    assert trajectory_stop_reason("elbow", "csp", "csp", status(faults=9), False) is None


@dataclass
class FakeEngine:
    is_panicked: bool = False  # a property of the native Engine


@dataclass
class FakeBus:
    engine: FakeEngine = field(default_factory=FakeEngine)


@dataclass
class FakeAxis:
    """What bridge and joints use of an Axis: the trajectory last started on it in csp as
    command 7 with 2 faults before."""

    name: str
    mode: str = "csp"
    bus: FakeBus = field(default_factory=FakeBus)

    def own_stop_reason(self, st: dict[str, Any], panicked: bool) -> str | None:
        return trajectory_stop_reason(self.name, "csp", self.mode, st, panicked, 2)

    def stopped_with_trajectory(self, st: dict[str, Any]) -> bool:
        return bool(st["trajectory_stopped"]) and st["command_seq"] == 7


def test_a_joints_own_reason_comes_before_stopped_with_its_trajectory() -> None:
    shoulder, elbow = FakeAxis("shoulder"), FakeAxis("elbow", mode="pv")
    statuses = [status(trajectory_stopped=True, trajectory_active=False),
                status(trajectory_stopped=True, trajectory_active=False)]  # fmt: skip
    assert bridge.trajectory_stop_reason([shoulder, elbow], statuses) == (
        "joint 'elbow' left csp (now pv)"
    )
    elbow.mode = "csp"
    assert bridge.trajectory_stop_reason([shoulder, elbow], statuses) == (
        stopped_with_trajectory("shoulder")
    )
    # The flag of a trajectory before this one (not replaced in the engine yet) is none.
    old = [status(trajectory_stopped=True, command_seq=6)] * 2
    assert bridge.trajectory_stop_reason([shoulder, elbow], old) is None
    shoulder.bus.engine.is_panicked = True
    halted = [status(halted=True), status(halted=True)]
    assert bridge.trajectory_stop_reason([shoulder, elbow], halted) == (
        "panic (joint 'shoulder' stopped)"
    )


def test_a_watched_trajectory_ends_well_replaced_or_with_a_reason() -> None:
    axes = [FakeAxis("shoulder"), FakeAxis("elbow")]
    plan = joints.TrajectoryPlan([(a, [(1.0, 0.1, 0.0)]) for a in axes], 0, 1_000_000_000)
    watch = joints.TrajectoryWatch(plan, 7)
    assert [a.name for a in watch.axes] == ["shoulder", "elbow"]
    # Running, or not taken over by the engine yet.
    assert watch.outcome([status(), status(command_seq=6)]) is None
    done = status(trajectory_done=True, trajectory_active=False)
    assert watch.outcome([done, done]) == joints.TrajectoryWatch.OVER
    # A newer command for one joint: that command answers for itself.
    assert watch.outcome([status(command_seq=8), status()]) == joints.TrajectoryWatch.OVER
    axes[1].mode = "csv"
    assert watch.outcome([done, status()]) == "joint 'elbow' left csp (now csv)"
