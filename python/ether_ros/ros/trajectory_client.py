"""A FollowJointTrajectory action client, as MoveIt's simple controller manager or
rqt_joint_trajectory_controller use the node's server (docs/ros.md, "FollowJointTrajectory"):
for the tests, the benchmark and scripts. It runs on the node of an ``EtherRosClient`` (whose
executor thread spins it)::

    with EtherRosClient() as c:
        fjt = TrajectoryActionClient(c.node)
        outcome = fjt.run(["elbow"], [(1.0, [0.3]), (2.0, [0.0])])
        outcome.error_code, outcome.error_string, len(outcome.feedback)
"""

from __future__ import annotations

import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

from builtin_interfaces.msg import Duration
from control_msgs.action import FollowJointTrajectory
from control_msgs.msg import JointTolerance
from rclpy.action import ActionClient
from trajectory_msgs.msg import JointTrajectoryPoint

from ether_ros.errors import EtherRosError

Result = FollowJointTrajectory.Result


class TrajectoryActionError(EtherRosError):
    """The server did not answer (not there, or a goal or result timed out)."""


def duration(seconds: float) -> Duration:
    ns = round(seconds * 1e9)
    return Duration(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)


def make_goal(
    names: Sequence[str],
    points: Sequence[tuple[float, Sequence[float]]],
    velocities: Sequence[Sequence[float]] | None = None,
    start: float = 0.0,
    path_tolerance: dict[str, float] | None = None,
    goal_tolerance: dict[str, float] | None = None,
    goal_time_tolerance: float = 0.0,
) -> Any:
    """A goal: ``points`` are (time_from_start s, positions); ``start`` the header stamp in
    wall-clock seconds (0: now); tolerances are position tolerances by joint name."""
    goal = FollowJointTrajectory.Goal()
    if start:
        ns = int(start * 1e9)
        goal.trajectory.header.stamp.sec, goal.trajectory.header.stamp.nanosec = divmod(
            ns, 1_000_000_000
        )
    goal.trajectory.joint_names = list(names)
    for i, (t, positions) in enumerate(points):
        p = JointTrajectoryPoint()
        p.positions = [float(x) for x in positions]
        if velocities is not None:
            p.velocities = [float(x) for x in velocities[i]]
        p.time_from_start = duration(t)
        goal.trajectory.points.append(p)
    goal.path_tolerance = [
        JointTolerance(name=n, position=float(v)) for n, v in (path_tolerance or {}).items()
    ]
    goal.goal_tolerance = [
        JointTolerance(name=n, position=float(v)) for n, v in (goal_tolerance or {}).items()
    ]
    goal.goal_time_tolerance = duration(goal_time_tolerance)
    return goal


@dataclass
class Outcome:
    """How a goal ended: its status (``action_msgs/GoalStatus``: 4 succeeded, 5 canceled, 6
    aborted), the result code and text, every feedback received with its arrival time, and when
    the result arrived."""

    status: int = 0
    error_code: int = 0
    error_string: str = ""
    feedback: list[tuple[float, Any]] = field(default_factory=list)
    # When the result arrived (time.monotonic(), this process): for latency measurements.
    ended_at: float = 0.0


class GoalRun:
    """A goal on its way: ``wait()`` for its outcome, ``cancel()`` it."""

    def __init__(self, handle: Any, outcome: Outcome, done: threading.Event) -> None:
        self._handle = handle
        self.outcome = outcome
        self._done = done

    def cancel(self, timeout: float = 5.0) -> None:
        future = self._handle.cancel_goal_async()
        _wait(future, timeout, "the cancel")

    def wait(self, timeout: float = 30.0) -> Outcome:
        if not self._done.wait(timeout):
            raise TrajectoryActionError(f"no result within {timeout:g} s")
        return self.outcome


def _wait(future: Any, timeout: float, what: str) -> Any:
    deadline = time.monotonic() + timeout
    while not future.done():
        if time.monotonic() > deadline:
            raise TrajectoryActionError(f"{what}: no answer within {timeout:g} s")
        time.sleep(0.002)
    return future.result()


class TrajectoryActionClient:
    """The client of the node's FollowJointTrajectory server on ``node`` (spun elsewhere);
    ``name`` relative to the node's namespace, as ``ros.trajectory_action``."""

    def __init__(self, node: Any, name: str = "follow_joint_trajectory") -> None:
        self.client = ActionClient(node, FollowJointTrajectory, name)

    def send(self, goal: Any, timeout: float = 10.0) -> GoalRun:
        if not self.client.wait_for_server(timeout_sec=timeout):
            raise TrajectoryActionError("no FollowJointTrajectory server")
        outcome = Outcome()
        done = threading.Event()

        def on_feedback(msg: Any) -> None:
            outcome.feedback.append((time.monotonic(), msg.feedback))

        handle = _wait(
            self.client.send_goal_async(goal, feedback_callback=on_feedback), timeout, "the goal"
        )
        if not handle.accepted:
            raise TrajectoryActionError("the goal was rejected")

        def on_result(future: Any) -> None:
            response = future.result()
            outcome.status = int(response.status)
            outcome.error_code = int(response.result.error_code)
            outcome.error_string = str(response.result.error_string)
            outcome.ended_at = time.monotonic()
            done.set()

        handle.get_result_async().add_done_callback(on_result)
        return GoalRun(handle, outcome, done)

    def run(self, *args: Any, timeout: float = 30.0, **kwargs: Any) -> Outcome:
        """``make_goal(*args, **kwargs)``, sent and waited for."""
        return self.send(make_goal(*args, **kwargs)).wait(timeout)

    def destroy(self) -> None:
        self.client.destroy()
