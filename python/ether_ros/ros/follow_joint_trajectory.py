"""The ``control_msgs/action/FollowJointTrajectory`` server of the node: the CiA 402 axes as a
JointTrajectoryController for MoveIt's simple controller manager, rqt_joint_trajectory_controller
or any action client (docs/ros.md, "FollowJointTrajectory").

A goal is checked as a whole before anything moves: the joints (INVALID_JOINTS: unknown,
repeated, none, multi-DOF), the trajectory and tolerances (INVALID_GOAL: times not increasing,
NaN or inf, values or velocities beyond the limits, a joint not enabled or not in csp/csv), and
its time (OLD_HEADER_TIMESTAMP: it ends in the past, or its first point lies further in the past
than the goal time tolerance). An accepted goal goes to the engine in one
hand-over (every joint starts in the same cycle) and replaces the rest of the running goal, as
with JointTrajectoryController; the replaced goal ends aborted with INVALID_GOAL and a message
saying it was replaced. While it runs, feedback (desired, actual, error) goes out at 100 Hz and
the path tolerances are checked; after its end the goal tolerances, for up to
goal_time_tolerance. A cancel or a violated tolerance stops the joints with a quiet stop at
their configured deceleration. Every goal ends: one whose joint leaves the state the trajectory
needs (mode change, disable, fault, quick stop, panic, watchdog; the lease lapsing; the bus
stopping) ends aborted with ``STOPPED`` and the reason, the period after the server sees it (the
engine has already stopped the goal's other joints quietly).

While the node's control lease is on (docs/security.md), a goal is the holder's when the client
that sent it is (its goal-reply reader is one the holder registered, or belongs to one of its
``writer_nodes``); any other goal ends aborted with INVALID_GOAL naming the holder, and the
running goal goes on.

Talks to the axes through :mod:`ether_ros.ros.bridge` and :mod:`ether_ros.ros.joints` only.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

from control_msgs.action import FollowJointTrajectory
from rclpy.action import ActionServer, CancelResponse, GoalResponse
from rclpy.callback_groups import ReentrantCallbackGroup
from trajectory_msgs.msg import JointTrajectoryPoint

from ether_ros.errors import EtherRosError
from ether_ros.ros import bridge, joints
from ether_ros.ros.lease import request_sender

Result = FollowJointTrajectory.Result
# Feedback and supervision period (s): 100 Hz.
PERIOD_S = 0.01
# A tolerance given as this means: not checked for this joint (control_msgs/JointTolerance).
ERASED = -1.0
# The result code of a goal that ends because a joint of it can no longer follow it: mode
# change, disable, fault, quick stop, panic, watchdog, the control lease lapsing, the bus stopping
# (the reason goes into error_string). control_msgs has no generic failure code, only these.
# MoveIt's simple controller manager treats every aborted goal alike (it logs the code's name
# and error_string, ends the execution ABORTED, move_group reports CONTROL_FAILED and does not
# replan), so the code is for people and other clients: INVALID_GOAL would say the goal was
# wrong (resending it after the joint is back is right), PATH_/GOAL_TOLERANCE_VIOLATED that
# the motion deviated (widening a tolerance would be the wrong fix), OLD_HEADER_TIMESTAMP is
# about time. INVALID_JOINTS -- the goal's joints are not joints this controller can drive --
# is what it is while a joint is out of its mode, disabled or stopped (docs/ros.md).
STOPPED = Result.INVALID_JOINTS


# Who may command: raises EtherRosError (naming the lease's holder) unless the client that sent
# a goal (its GID; None: unknown) may command now.
SenderGate = Callable[[bytes | None], None]


class _SenderAwareActionServer(ActionServer):
    """An ActionServer that remembers who sent each goal request (by goal id), for the gate."""

    def __init__(self, *args: Any, senders: dict[bytes, bytes | None], **kwargs: Any) -> None:
        self._senders = senders
        super().__init__(*args, **kwargs)

    async def _execute_goal_request(self, request_header_and_message: Any) -> None:
        header, request = request_header_and_message
        self._senders[bytes(request.goal_id.uuid)] = request_sender(header)
        await super()._execute_goal_request(request_header_and_message)


class GoalRefused(EtherRosError):
    """A goal refused before anything moved, with its FollowJointTrajectory result code."""

    def __init__(self, code: int, message: str) -> None:
        super().__init__(message)
        self.code = code


@dataclass(frozen=True)
class Tolerance:
    """Per joint, the largest |error| allowed (SI); 0: not checked."""

    position: float = 0.0
    velocity: float = 0.0


@dataclass
class GoalRun:
    """A goal as the server runs it."""

    plan: joints.TrajectoryPlan | None = None
    refusal: GoalRefused | None = None
    path: dict[str, Tolerance] = field(default_factory=dict)
    goal: dict[str, Tolerance] = field(default_factory=dict)
    goal_time_s: float = 0.0
    # The final point of every joint: (position, velocity).
    final: dict[str, tuple[float, float]] = field(default_factory=dict)
    # The engine's number of the goal's trajectory (its axes' command_seq while it runs).
    seq: int = 0
    replaced: bool = False
    # Ended by the node (``FollowJointTrajectoryServer.end_goals``): the reason.
    ended: str | None = None


def duration_s(d: Any) -> float:
    return float(d.sec) + float(d.nanosec) * 1e-9


def resolve_tolerances(
    given: Any, names: list[str], default_position: float, what: str
) -> dict[str, Tolerance]:
    """The tolerance of every joint of the goal from a JointTolerance[] (0: the server's
    default; -1: not checked; by joint name). Refused: a joint not in the trajectory, NaN, a
    negative value other than -1."""
    out = {n: Tolerance(position=default_position) for n in names}
    for t in given:
        if t.name not in out:
            raise GoalRefused(Result.INVALID_GOAL, f"{what} for joint {t.name!r}, which the "
                              f"trajectory does not name ({', '.join(names)})")  # fmt: skip
        values = {}
        for key in ("position", "velocity", "acceleration"):
            v = float(getattr(t, key))
            if math.isnan(v) or math.isinf(v) or (v < 0 and v != ERASED):
                raise GoalRefused(Result.INVALID_GOAL, f"{what} of joint {t.name!r}: {key} {v!r} "
                                  "must be >= 0, or -1 for none")  # fmt: skip
            values[key] = v
        current = out[t.name]
        position = {0.0: current.position, ERASED: 0.0}.get(values["position"], values["position"])
        velocity = {0.0: current.velocity, ERASED: 0.0}.get(values["velocity"], values["velocity"])
        out[t.name] = Tolerance(position, velocity)
    return out


def first_point_lateness(plan: joints.TrajectoryPlan, engine_now_ns: int) -> float:
    """How long ago (s) the trajectory's first point was due (≤ 0: it is not past yet)."""
    first_s = min(track[0][0] for _, track in plan.tracks)
    return (engine_now_ns - plan.start_ns) * 1e-9 - first_s


def check_goal(
    axes: Mapping[str, Any],
    goal: Any,
    capacity: int,
    defaults: Any,
    wall_now_ns: int,
    engine_now_ns: int,
) -> GoalRun:
    """A FollowJointTrajectory goal → the run the server executes, or GoalRefused with the
    standard code and a message; nothing is written either way."""
    if len(goal.multi_dof_trajectory.joint_names) or len(goal.multi_dof_trajectory.points):
        raise GoalRefused(Result.INVALID_JOINTS, "multi-DOF joints: this server has none (the "
                          "CiA 402 axes are single-DOF joints)")  # fmt: skip
    if len(goal.component_path_tolerance) or len(goal.component_goal_tolerance):
        raise GoalRefused(Result.INVALID_JOINTS, "component tolerances are for multi-DOF "
                          "joints: this server has none")  # fmt: skip
    try:
        plan = joints.trajectory_plan(axes, goal.trajectory, capacity, wall_now_ns, engine_now_ns)
    except joints.InvalidJoints as exc:
        raise GoalRefused(Result.INVALID_JOINTS, str(exc)) from None
    except joints.OldTimestamp as exc:
        raise GoalRefused(Result.OLD_HEADER_TIMESTAMP, str(exc)) from None
    except EtherRosError as exc:
        raise GoalRefused(Result.INVALID_GOAL, str(exc)) from None
    names = plan.names
    for axis, _track in plan.tracks:
        st = bridge.axis_status(axis)
        if st["state"] != "operation_enabled" or not st["mode_reached"] or st["restart_blocked"]:
            why = f"{st['state']}, mode {bridge.axis_mode(axis)}"
            if st["restart_blocked"]:
                why += ", waiting for an explicit enable"
            if st["faults"]:
                why += f", last fault 0x{st['last_fault_code']:04X}"
            raise GoalRefused(Result.INVALID_GOAL, f"joint {axis.name!r} is not enabled in its "
                              f"mode ({why}): call the enable service first")  # fmt: skip
    time_tolerance = duration_s(goal.goal_time_tolerance)
    if not math.isfinite(time_tolerance) or time_tolerance < 0:
        raise GoalRefused(Result.INVALID_GOAL, f"goal_time_tolerance {time_tolerance:g} s is "
                          "negative")  # fmt: skip
    goal_time_s = time_tolerance or defaults.goal_time_tolerance_s
    late_s = first_point_lateness(plan, engine_now_ns)
    if late_s > goal_time_s:
        # Joining a path that far along would be a different motion from the one planned
        # (docs/ros.md, "Hand-overs"); within the tolerance it is joined from the commanded
        # state like any other hand-over.
        raise GoalRefused(Result.OLD_HEADER_TIMESTAMP, f"the first point lies {late_s:.3f} s in "
                          f"the past, more than the goal time tolerance ({goal_time_s:g} s): "
                          "stamp the goal now (header.stamp 0) or later")  # fmt: skip
    return GoalRun(
        plan=plan,
        path=resolve_tolerances(
            goal.path_tolerance, names, defaults.path_tolerance, "path_tolerance"
        ),
        goal=resolve_tolerances(
            goal.goal_tolerance, names, defaults.goal_tolerance, "goal_tolerance"
        ),
        goal_time_s=goal_time_s,
        final={axis.name: (track[-1][1], track[-1][2]) for axis, track in plan.tracks},
    )


def _violation(
    name: str, st: Mapping[str, Any], tol: Tolerance, want: tuple[float, float], what: str
) -> str | None:
    """Why joint ``name`` is outside ``tol`` of (position, velocity) ``want``, or None."""
    position_error = want[0] - float(st["position"])
    velocity_error = want[1] - float(st["velocity"])
    if tol.position > 0 and abs(position_error) > tol.position:
        return (f"joint {name!r}: position error {position_error:+.5f} beyond the {what} "
                f"{tol.position:g}")  # fmt: skip
    if tol.velocity > 0 and abs(velocity_error) > tol.velocity:
        return (f"joint {name!r}: velocity error {velocity_error:+.5f} beyond the {what} "
                f"{tol.velocity:g}")  # fmt: skip
    return None


class FollowJointTrajectoryServer:
    """The action server on ``node`` (see the module doc). ``axes`` gives the active axes by
    joint name (raising ``EtherRosError`` when the node is not active), ``capacity`` the
    engine's points per trajectory, ``note_command`` tells the node a command came, ``gate``
    (if any) says who may send goals."""

    def __init__(
        self,
        node: Any,
        name: str,
        defaults: Any,
        axes: Callable[[], Mapping[str, Any]],
        capacity: Callable[[], int],
        note_command: Callable[[], None],
        gate: SenderGate | None = None,
    ) -> None:
        self._node = node
        self._defaults = defaults
        self._axes = axes
        self._capacity = capacity
        self._note_command = note_command
        self._gate = gate
        self._senders: dict[bytes, bytes | None] = {}
        self._lock = threading.Lock()
        self._runs: dict[bytes, GoalRun] = {}
        self._active: GoalRun | None = None
        self.server = _SenderAwareActionServer(
            node,
            FollowJointTrajectory,
            name,
            execute_callback=self._execute,
            goal_callback=lambda _goal: GoalResponse.ACCEPT,
            handle_accepted_callback=self._accepted,
            cancel_callback=lambda _handle: CancelResponse.ACCEPT,
            callback_group=ReentrantCallbackGroup(),
            senders=self._senders,
        )

    def destroy(self) -> None:
        self.server.destroy()

    def end_goals(self, reason: str) -> None:
        """End the running goal (aborted, ``STOPPED``) for ``reason``, which the axes' status
        cannot tell (the control lease lapsed): called before the node stops the motion, so the
        goal names the cause rather than what it did to the joints."""
        with self._lock:
            if self._active is not None:
                self._active.ended = reason

    # ------------------------------------------------------------------ goals
    def _accepted(self, handle: Any) -> None:
        """Every goal is accepted, so that a refusal carries its code and message; a valid one
        starts at once and replaces the running goal."""
        run = GoalRun()
        goal_id = bytes(handle.goal_id.uuid)
        sender = self._senders.pop(goal_id, None)
        try:
            if self._gate is not None:  # before anything, so a refused goal replaces nothing
                self._gate(sender)
            axes = self._axes()
            run = check_goal(axes, handle.request, self._capacity(), self._defaults,
                             time.time_ns(), bridge.engine_now_ns(axes))  # fmt: skip
        except GoalRefused as exc:
            run.refusal = exc
        except EtherRosError as exc:
            run.refusal = GoalRefused(Result.INVALID_GOAL, str(exc))
        if run.plan is not None:
            with self._lock:
                if self._active is not None:
                    self._active.replaced = True
                self._active = run
            try:
                self._note_command()
                run.seq = bridge.follow_plan(run.plan)
            except EtherRosError as exc:
                run.refusal = GoalRefused(Result.INVALID_GOAL, str(exc))
        self._runs[goal_id] = run
        handle.execute()

    def _execute(self, handle: Any) -> Any:
        run = self._runs.pop(bytes(handle.goal_id.uuid), None)
        if run is None or run.refusal is not None or run.plan is None:
            why = run.refusal if run is not None and run.refusal is not None else None
            handle.abort()
            return Result(
                error_code=why.code if why else Result.INVALID_GOAL,
                error_string=str(why) if why else "the goal was not checked",
            )
        try:
            return self._follow(handle, run)
        finally:
            with self._lock:
                if self._active is run:
                    self._active = None

    def _follow(self, handle: Any, run: GoalRun) -> Any:
        plan = run.plan
        assert plan is not None
        tracks = plan.tracks
        axes = [axis for axis, _ in tracks]
        names = plan.names
        seq = run.seq
        feedback = FollowJointTrajectory.Feedback()
        feedback.joint_names = names
        while True:
            if handle.is_cancel_requested:
                bridge.quiet_stop(axes)
                handle.canceled()
                return Result(error_code=Result.SUCCESSFUL,
                              error_string="canceled: the joints make a quiet stop")  # fmt: skip
            if run.replaced:
                handle.abort()
                return Result(error_code=Result.INVALID_GOAL,
                              error_string="replaced by a newer goal")  # fmt: skip
            if run.ended is not None:
                handle.abort()
                return Result(error_code=STOPPED, error_string=run.ended)
            try:
                statuses = [bridge.axis_status(a) for a in axes]
                now = bridge.engine_now_ns({a.name: a for a in axes})
            except EtherRosError as exc:
                handle.abort()
                return Result(error_code=STOPPED, error_string=f"the bus stopped: {exc}")
            for name, st in zip(names, statuses, strict=True):
                if int(st["command_seq"]) > seq:
                    handle.abort()
                    return Result(error_code=Result.INVALID_GOAL, error_string=(
                        f"joint {name!r} was given another command (joint_trajectory, "
                        "joint_commands or a service): the goal ends"))  # fmt: skip
            why = bridge.trajectory_stop_reason(axes, statuses)
            if why is not None:
                # No stop from here: the engine ended the trajectory on every joint of it
                # already (a quiet stop, or the joint's own stop), and a stop sent now could
                # land after a command the joint was given in its new mode.
                handle.abort()
                # A lapse noted meanwhile is the cause of what the joints show.
                return Result(error_code=STOPPED, error_string=run.ended or why)
            self._publish_feedback(handle, feedback, statuses, max(now - plan.start_ns, 0))
            # Until the engine has taken the trajectory over (command_seq) and run it to its end.
            running = now <= plan.end_ns or not all(
                int(st["command_seq"]) == seq and st["trajectory_done"] for st in statuses
            )
            if running:
                for name, st in zip(names, statuses, strict=True):
                    desired = (float(st["target_position"]), float(st["desired_velocity"]))
                    why = _violation(name, st, run.path[name], desired, "path tolerance")
                    if why is not None:
                        bridge.quiet_stop(axes)
                        handle.abort()
                        return Result(error_code=Result.PATH_TOLERANCE_VIOLATED,
                                      error_string=f"{why} at t = "
                                      f"{(now - plan.start_ns) * 1e-9:.3f} s")  # fmt: skip
            else:
                misses = [
                    why
                    for name, st in zip(names, statuses, strict=True)
                    if (
                        why := _violation(
                            name, st, run.goal[name], run.final[name], "goal tolerance"
                        )
                    )
                    is not None
                ]
                if not misses:
                    handle.succeed()
                    return Result(error_code=Result.SUCCESSFUL, error_string="")
                if (now - plan.end_ns) * 1e-9 > run.goal_time_s:
                    handle.abort()
                    more = f" (and {len(misses) - 1} more)" if len(misses) > 1 else ""
                    return Result(
                        error_code=Result.GOAL_TOLERANCE_VIOLATED,
                        error_string=(
                            f"{misses[0]} {run.goal_time_s:g} s after the trajectory's end{more}"
                        ),
                    )
            time.sleep(PERIOD_S)

    def _publish_feedback(
        self, handle: Any, feedback: Any, statuses: list[dict[str, Any]], t_ns: int
    ) -> None:
        desired, actual, error = (
            JointTrajectoryPoint(),
            JointTrajectoryPoint(),
            JointTrajectoryPoint(),
        )
        desired.positions = [float(st["target_position"]) for st in statuses]
        desired.velocities = [float(st["desired_velocity"]) for st in statuses]
        actual.positions = [float(st["position"]) for st in statuses]
        actual.velocities = [float(st["velocity"]) for st in statuses]
        actual.effort = [float(st["torque"]) for st in statuses]
        error.positions = [d - a for d, a in zip(desired.positions, actual.positions, strict=True)]
        error.velocities = [
            d - a for d, a in zip(desired.velocities, actual.velocities, strict=True)
        ]
        for point in (desired, actual, error):
            point.time_from_start.sec = int(t_ns // 1_000_000_000)
            point.time_from_start.nanosec = int(t_ns % 1_000_000_000)
        feedback.header.stamp = self._node.get_clock().now().to_msg()
        feedback.desired, feedback.actual, feedback.error = desired, actual, error
        handle.publish_feedback(feedback)
