"""The arm (config/arm6.yaml) driven through ``control_msgs/action/FollowJointTrajectory`` as
MoveIt's simple controller manager drives a JointTrajectoryController: the simulator and the
node run as their own processes on the two ends of a veth pair; this process is a separate
rclpy action client with a ROS domain of its own. Nothing is faked.

Covers: a goal for all six joints succeeds with feedback (desired, actual, error) at 50 Hz or
more; a path tolerance and a goal tolerance violated give their result codes and leave the arm
standing without a fault; a cancel and a preemption stop the running goal smoothly (the axes'
position targets, read back as the feedback's desired positions, never jump); bad goals are
refused with the standard code and a message, and nothing moves. Timing is never asserted
beyond the feedback's rate over a whole goal.
"""

from __future__ import annotations

import itertools
import math
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from ether_ros.ros.client import EtherRosClient
from ether_ros.ros.rig import RosRig
from ether_ros.ros.trajectory_client import Result, TrajectoryActionClient, make_goal

pytestmark = [pytest.mark.netns, pytest.mark.ros, pytest.mark.slow]

REPO = Path(__file__).resolve().parents[2]
JOINTS = ["shoulder_pan", "shoulder_lift", "elbow", "wrist_1", "wrist_2", "wrist_3"]
SUCCEEDED, CANCELED, ABORTED = 4, 5, 6
# The largest step of a position target per 10 ms of feedback at the joints' velocity limits
# (4 rad/s): anything larger is a jump.
MAX_STEP = 4.0 * 0.012


@pytest.fixture(scope="module")
def rig(veth_allowed: bool) -> Iterator[RosRig]:
    if not veth_allowed:
        pytest.fail("the ROS acceptance tests need root (veth pairs)")
    with RosRig(REPO / "config" / "arm6.yaml", netns=True) as rig:
        assert rig.client.wait_for_node() == "active"
        ok, message, states = rig.client.axis_command("enable")
        assert ok, message
        assert states == dict.fromkeys(JOINTS, "operation_enabled")
        yield rig


@pytest.fixture(scope="module")
def fjt(rig: RosRig) -> TrajectoryActionClient:
    return TrajectoryActionClient(rig.client.node)


def positions(client: EtherRosClient) -> dict[str, float]:
    msg = client.wait_for(lambda latest: latest.joint_state, timeout=5)
    return dict(zip(msg.name, msg.position, strict=True))


def home(fjt: TrajectoryActionClient, client: EtherRosClient) -> dict[str, float]:
    """All joints to 0 (a goal that must succeed); the positions afterwards."""
    here = positions(client)
    far = max(abs(p) for p in here.values())
    outcome = fjt.run(JOINTS, [(max(far / 0.5, 0.5), [0.0] * 6)])
    assert outcome.status == SUCCEEDED, outcome
    return positions(client)


def desired_steps(outcome: object) -> float:
    """The largest change of any joint's desired position between two feedback messages."""
    fb = [f for _, f in outcome.feedback]  # type: ignore[attr-defined]
    steps = (
        abs(q - p)
        for a, b in itertools.pairwise(fb)
        for p, q in zip(a.desired.positions, b.desired.positions, strict=True)
    )
    return max(steps, default=0.0)


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
    now = positions(client)
    assert all(abs(now[j] - t) < 0.005 for j, t in zip(JOINTS, targets, strict=True)), now
    fb = outcome.feedback
    assert len(fb) > 10
    rate = (len(fb) - 1) / (fb[-1][0] - fb[0][0])
    assert rate >= 50.0, rate
    last = fb[-1][1]
    assert list(last.joint_names) == JOINTS
    for d, a, e in zip(last.desired.positions, last.actual.positions, last.error.positions,
                       strict=True):  # fmt: skip
        assert math.isclose(e, d - a, abs_tol=1e-12)
    assert desired_steps(outcome) < MAX_STEP


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
    time.sleep(0.5)
    stopped = positions(client)["elbow"]
    assert 0.0 < stopped < 0.55, stopped
    home(fjt, client)


def test_a_violated_goal_tolerance_aborts(rig: RosRig, fjt: TrajectoryActionClient) -> None:
    client = rig.client
    home(fjt, client)
    # The drive is a few mrad behind at the end of a fast move; 1 ms of goal time is too short
    # to come within 10 µrad.
    outcome = fjt.run(["elbow"], [(0.3, [0.5])], goal_tolerance={"elbow": 1e-5},
                      goal_time_tolerance=0.001)  # fmt: skip
    assert (outcome.status, outcome.error_code) == (ABORTED, Result.GOAL_TOLERANCE_VIOLATED)
    assert "goal tolerance 1e-05" in outcome.error_string, outcome.error_string
    home(fjt, client)


def test_a_cancel_stops_the_joint_smoothly(rig: RosRig, fjt: TrajectoryActionClient) -> None:
    client = rig.client
    home(fjt, client)
    run = fjt.send(make_goal(["wrist_2"], [(2.0, [1.0])]))
    deadline = time.monotonic() + 10
    while positions(client)["wrist_2"] < 0.2:
        assert time.monotonic() < deadline, "the goal did not start"
        time.sleep(0.01)
    run.cancel()
    outcome = run.wait()
    assert (outcome.status, outcome.error_code) == (CANCELED, Result.SUCCESSFUL), outcome
    time.sleep(0.5)
    stopped = positions(client)["wrist_2"]
    assert 0.2 < stopped < 0.95, stopped
    assert desired_steps(outcome) < MAX_STEP
    home(fjt, client)


def test_a_new_goal_preempts_the_running_one_without_a_jump(
    rig: RosRig, fjt: TrajectoryActionClient
) -> None:
    client = rig.client
    home(fjt, client)
    first = fjt.send(make_goal(["elbow", "wrist_1"], [(2.0, [1.0, -1.0])]))
    deadline = time.monotonic() + 10
    while positions(client)["elbow"] < 0.2:
        assert time.monotonic() < deadline, "the goal did not start"
        time.sleep(0.01)
    second = fjt.send(make_goal(["elbow", "wrist_1"], [(1.0, [0.1, -0.1])]))
    old = first.wait()
    assert (old.status, old.error_code) == (ABORTED, Result.INVALID_GOAL), old
    assert "replaced by a newer goal" in old.error_string
    new = second.wait()
    assert (new.status, new.error_code) == (SUCCEEDED, Result.SUCCESSFUL), new
    assert desired_steps(new) < MAX_STEP
    now = positions(client)
    assert abs(now["elbow"] - 0.1) < 0.01 and abs(now["wrist_1"] + 0.1) < 0.01, now


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
    before = positions(client)
    outcome = fjt.run(names, points, **kwargs)  # type: ignore[arg-type]
    assert (outcome.status, outcome.error_code) == (ABORTED, code), outcome
    assert why in outcome.error_string, outcome.error_string
    time.sleep(0.2)
    after = positions(client)
    assert all(abs(after[j] - before[j]) < 1e-3 for j in JOINTS), (before, after)
