"""CiA 402 axes as ROS joints: ``joint_trajectory`` messages turned into checked engine
trajectories, and the axes' part of ``joint_states``. Talks to the axes through
:mod:`ether_ros.ros.bridge` only (docs/ros.md, "Joints").
"""

from __future__ import annotations

import math
import struct
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from ether_ros import _native
from ether_ros.config.cia402 import acceleration_limit
from ether_ros.errors import EtherRosError
from ether_ros.ros import bridge
from ether_ros.ros.bridge import AxisRejected

# A start further ahead than this is taken for a clock mix-up and refused.
STAMP_FUTURE_LIMIT_S = 60.0

Point = tuple[float, float, float]  # (t s, position, velocity)


class InvalidJoints(AxisRejected):
    """The joints of a trajectory do not fit the bus's axes (unknown, repeated, none, or joints
    with several degrees of freedom): FollowJointTrajectory's INVALID_JOINTS."""


class OldTimestamp(AxisRejected):
    """The whole trajectory lies in the past: FollowJointTrajectory's OLD_HEADER_TIMESTAMP."""


@dataclass(frozen=True)
class TrajectoryPlan:
    """A checked trajectory for the engine: (axis, points) per joint, with times from
    ``start_ns`` on the engine's clock (which may lie in the past: the engine trims the points
    already past), and when it ends."""

    tracks: list[tuple[Any, list[Point]]]
    start_ns: int
    end_ns: int

    @property
    def names(self) -> list[str]:
        return [axis.name for axis, _ in self.tracks]


@dataclass
class TrajectoryWatch:
    """A trajectory handed to the engine (``bridge.follow_plan``: its command number ``seq``),
    watched until it ends."""

    plan: TrajectoryPlan
    seq: int

    # ``outcome``: it ended well, or a newer command replaced it (nothing to report).
    OVER = ""

    @property
    def axes(self) -> list[Any]:
        return [axis for axis, _ in self.plan.tracks]

    def outcome(self, statuses: Sequence[Mapping[str, Any]]) -> str | None:
        """From its joints' statuses just read: None while it runs; ``OVER`` once it ran to its
        end or a joint was given a newer command; else why it cannot end
        (``bridge.trajectory_stop_reason``)."""
        if any(int(st["command_seq"]) > self.seq for st in statuses):
            return self.OVER
        if all(
            int(st["command_seq"]) == self.seq and st["trajectory_done"]
            and not st["trajectory_active"]
            for st in statuses
        ):  # fmt: skip
            return self.OVER
        return bridge.trajectory_stop_reason(self.axes, statuses)


def duration_s(d: Any) -> float:
    return float(d.sec) + float(d.nanosec) * 1e-9


def stamp_ns(t: Any) -> int:
    return int(t.sec) * 1_000_000_000 + int(t.nanosec)


def start_on_engine_clock(stamp: int, wall_now_ns: int, engine_now_ns: int) -> int:
    """``header.stamp`` (wall clock; zero: now) as a time on the engine's clock. A stamp in the
    past stays in the past: the points whose time has passed are trimmed (docs/ros.md)."""
    if stamp == 0:
        return engine_now_ns
    delay = stamp - wall_now_ns
    if delay > STAMP_FUTURE_LIMIT_S * 1e9:
        raise AxisRejected(
            f"header.stamp lies {delay * 1e-9:.1f} s ahead (more than {STAMP_FUTURE_LIMIT_S:g} s)"
        )
    return engine_now_ns + delay


def estimated_velocities(times: list[float], positions: list[float]) -> list[float]:
    """Velocities for waypoints given without them: at rest at both ends, the mean of the
    neighbouring slopes inside, and at rest where the motion turns (no overshoot)."""
    v = [0.0] * len(times)
    for i in range(1, len(times) - 1):
        before = (positions[i] - positions[i - 1]) / (times[i] - times[i - 1])
        after = (positions[i + 1] - positions[i]) / (times[i + 1] - times[i])
        if before * after > 0:
            v[i] = (before + after) / 2
    return v


def trajectory_plan(
    axes: Mapping[str, Any],
    msg: Any,
    capacity: int,
    wall_now_ns: int,
    engine_now_ns: int,
) -> TrajectoryPlan:
    """A JointTrajectory → the checked engine trajectory of every joint named, all or nothing
    (raises ``InvalidJoints``, ``OldTimestamp`` or ``AxisRejected`` naming what is wrong).

    time_from_start counts from ``header.stamp``. From the cycle the engine takes it over,
    every joint continues from the state it is commanded to have (the engine splices it in), so
    nothing jumps and a trajectory replaces the rest of a running one smoothly; a stamp in the
    past trims the points already past. Positions are required for joints in csp, velocities
    for csv; velocities missing in csp are estimated (``estimated_velocities``)."""
    names = list(msg.joint_names)
    if not names:
        raise InvalidJoints("the trajectory names no joint")
    if len(set(names)) != len(names):
        twice = sorted({n for n in names if names.count(n) > 1})
        raise InvalidJoints(f"the trajectory names joint(s) {', '.join(twice)} twice")
    if not axes:
        raise InvalidJoints("this bus has no CiA 402 axes")
    unknown = [n for n in names if n not in axes]
    if unknown:
        raise InvalidJoints(
            f"unknown joint(s) {', '.join(map(repr, unknown))} (joints: {', '.join(axes)})"
        )
    chosen = [axes[n] for n in names]
    points = list(msg.points)
    if not points:
        raise AxisRejected("the trajectory has no points")
    if capacity and len(points) > capacity:
        raise AxisRejected(f"the trajectory has {len(points)} points; at most {capacity} are taken")
    times = [duration_s(p.time_from_start) for p in points]
    for i, t in enumerate(times):
        if not math.isfinite(t) or t < 0 or (i and t <= times[i - 1]):
            raise AxisRejected(
                f"point {i}: time_from_start {t:g} s is not after the previous point's"
                if i
                else f"point 0: time_from_start {t:g} s is negative"
            )
    n = len(names)
    for i, p in enumerate(points):
        for label in ("positions", "velocities"):
            values = list(getattr(p, label))
            if len(values) not in (0, n):
                raise AxisRejected(
                    f"point {i}: {len(values)} {label} for {n} joints (give one per joint, or none)"
                )
            bad = [names[j] for j, x in enumerate(values) if not math.isfinite(x)]
            if bad:
                raise AxisRejected(f"point {i}: {label} of {', '.join(bad)} not finite")
    start_ns = start_on_engine_clock(stamp_ns(msg.header.stamp), wall_now_ns, engine_now_ns)
    end_ns = start_ns + round(times[-1] * 1e9)
    if end_ns < engine_now_ns:
        raise OldTimestamp(
            f"the trajectory ended {(engine_now_ns - end_ns) * 1e-9:.3f} s ago (header.stamp "
            "plus the last point's time_from_start lies in the past)"
        )
    tracks = []
    for j, axis in enumerate(chosen):
        kind = bridge.setpoint_kind(axis)
        needed = "positions" if kind == "position" else "velocities"
        missing = [i for i, p in enumerate(points) if not len(getattr(p, needed))]
        if kind in ("position", "velocity") and missing:
            raise AxisRejected(
                f"joint {axis.name!r} is in mode {bridge.axis_mode(axis)}: point {missing[0]} "
                f"gives no {needed}"
            )
        positions = [float(p.positions[j]) if len(p.positions) else 0.0 for p in points]
        velocities = [float(p.velocities[j]) if len(p.velocities) else math.nan for p in points]
        if kind == "position" and any(math.isnan(v) for v in velocities):
            velocities = estimated_velocities(times, positions)
        velocities = [0.0 if math.isnan(v) else v for v in velocities]
        track = list(zip(times, positions, velocities, strict=True))
        try:
            axis.check_trajectory(track)
        except EtherRosError as exc:
            raise AxisRejected(str(exc)) from None
        if kind == "position":
            _check_approach(axis, positions[0], (start_ns - engine_now_ns) * 1e-9 + times[0])
        tracks.append((axis, track))
    return TrajectoryPlan(tracks, start_ns, end_ns)


def _check_approach(axis: Any, first: float, within: float) -> None:
    """The way from where the axis is commanded to be now to the trajectory's first point,
    ``within`` seconds: refused when it needs more than the velocity limit, or more than the
    acceleration limit (``max_acceleration``, default the deceleration: docs/cia402.md) starting
    from the velocity the axis is commanded to have — the engine would join the path within
    the limits and arrive late, off the trajectory's timing. A first point at
    time 0 (of a goal stamped now) or already past is no target: the engine replaces it with the
    axis's commanded state and joins the rest of the path from there within the axis's
    acceleration and velocity limits, never steering back to it (docs/ros.md, "Hand-overs")."""
    if within <= 0:
        return
    st = bridge.axis_status(axis)
    enabled = st["state"] == "operation_enabled"
    here = float(st["target_position"] if enabled else st["position"])
    config = axis.spec.config
    limit = float(config.velocity_limit)
    distance = first - here
    speed = abs(distance) / within
    if speed > limit * (1 + 1e-9):
        raise AxisRejected(
            f"joint {axis.name!r}: from {here:.4g} to the first point {first:g} in {within:.3f} s "
            f"needs {speed:.3g} on average, beyond the velocity limit ±{limit:g}"
        )
    amax = float(acceleration_limit(config))
    if not math.isfinite(amax):
        return
    # The least constant acceleration that covers the distance in the time, from the velocity
    # the axis has now: distance = v0·t + a·t²/2.
    v0 = float(st.get("desired_velocity", 0.0) or 0.0) if enabled else 0.0
    needed = 2.0 * abs(distance - v0 * within) / (within * within)
    if needed > amax * (1 + 1e-9):
        raise AxisRejected(
            f"joint {axis.name!r}: the first point {first:g} lies {abs(distance):.4g} from where "
            f"the joint is commanded to be ({here:.4g}, moving at {v0:.3g}); reaching it in "
            f"{within:.3f} s needs an acceleration of {needed:.3g}, beyond the acceleration limit "
            f"{amax:g} (max_acceleration, default the deceleration)"
        )


class AxisImageJoints:
    """(joint, position, velocity, effort) of every axis in SI, for ``joint_states``, read from
    one cycle's process image with the engine plan's offsets and scales, converted as the
    engine converts them (position = raw × scale + offset, velocity and torque raw × scale; an
    object the PDOs do not map reads raw 0). Read from the sample rather than from the axis's
    status now, a message carries the values of the cycle whose stamp it has, also when the
    publisher works through a backlog after a stall."""

    def __init__(self, plan_axes: Sequence[_native.AxisPlan]) -> None:
        self._axes = [
            (
                e.name,
                e.map.position,
                e.map.velocity,
                e.map.torque,
                e.position_scale,
                e.position_offset,
                e.velocity_scale,
                e.torque_scale,
            )
            for e in plan_axes
        ]

    def __call__(self, image: bytes) -> list[tuple[str, float, float, float]]:
        out = []
        for name, p, v, t, p_scale, p_offset, v_scale, t_scale in self._axes:
            p_raw = _I32.unpack_from(image, p)[0] if p is not None else 0
            v_raw = _I32.unpack_from(image, v)[0] if v is not None else 0
            t_raw = _I16.unpack_from(image, t)[0] if t is not None else 0
            out.append((name, p_raw * p_scale + p_offset, v_raw * v_scale, t_raw * t_scale))
        return out


_I32 = struct.Struct("<i")  # 0x6064 position / 0x606C velocity actual value (DINT)
_I16 = struct.Struct("<h")  # 0x6077 torque actual value (INT)


def axis_extra_values(axes: Mapping[str, Any]) -> list[tuple[str, str, float]]:
    """(joint, extra, value in SI) of every axis's extras (``Axis.extras``), for
    ``joint_extras``: axes in bus order, each axis's extras in configuration order."""
    out: list[tuple[str, str, float]] = []
    for name, axis in axes.items():
        try:
            values = axis.extras
        except EtherRosError:
            continue  # the bus stopped meanwhile: the next message has them again
        out.extend((name, extra, float(value)) for extra, value in values.items())
    return out


def has_extras(axes: Mapping[str, Any]) -> bool:
    """Whether some axis has ``extras:`` configured (``joint_extras`` is published then)."""
    return any(axis.spec.extras for axis in axes.values())


@dataclass(frozen=True)
class AxisState:
    """One axis's entry in ``joint_extras``' per-axis arrays: the state the diagnostics report
    for it (``diagnostics.axis_statuses``), from its status, its commanded mode, the bus's panic
    and what stopped it as the node saw it."""

    joint: str
    state: str
    enable_wanted: bool
    mode_reached: bool
    restart_blocked: bool
    limit_active: bool
    outside_limits: bool
    stopped_by: str
    blocked: str


def axis_state(joint: str, mode: str, st: Mapping[str, Any], panic: bool, cause: str) -> AxisState:
    """The ``AxisState`` of axis ``joint`` from its ``Axis.status()`` ``st``: ``blocked`` is
    ``bridge.axis_blocker``'s sentence, as in the diagnostics."""
    return AxisState(
        joint=joint,
        state=str(st.get("state", "")),
        enable_wanted=bool(st.get("enable_wanted", False)),
        mode_reached=bool(st.get("mode_reached", False)),
        restart_blocked=bool(st.get("restart_blocked", False)),
        limit_active=bool(st.get("limit_active", False)),
        outside_limits=bool(st.get("outside_limits", False)),
        stopped_by=cause,
        blocked=bridge.axis_blocker(st, mode, panic, cause=cause),
    )
