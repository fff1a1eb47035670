"""CiA 402 axes as ROS joints: ``joint_trajectory`` messages turned into checked engine
trajectories, and the axes' part of ``joint_states``. Talks to the axes through
:mod:`ether_ros.ros.bridge` only (docs/ros.md, "Joints").
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

from ether_ros.errors import EtherRosError
from ether_ros.ros import bridge
from ether_ros.ros.bridge import AxisRejected

# A header.stamp this far in the past still starts the trajectory (now); older ones are
# refused, since the engine would have to jump into the middle of it.
STAMP_PAST_TOLERANCE_S = 0.1
# A start further ahead than this is taken for a clock mix-up and refused.
STAMP_FUTURE_LIMIT_S = 60.0

Point = tuple[float, float, float]  # (t s, position, velocity)


def duration_s(d: Any) -> float:
    return float(d.sec) + float(d.nanosec) * 1e-9


def stamp_ns(t: Any) -> int:
    return int(t.sec) * 1_000_000_000 + int(t.nanosec)


def start_delay(stamp: int, now_ns: int) -> float:
    """Seconds from now until ``header.stamp`` (a zero stamp: now)."""
    if stamp == 0:
        return 0.0
    delay = (stamp - now_ns) * 1e-9
    if delay < -STAMP_PAST_TOLERANCE_S:
        raise AxisRejected(f"header.stamp lies {-delay:.3f} s in the past (zero stamp: start now)")
    if delay > STAMP_FUTURE_LIMIT_S:
        raise AxisRejected(
            f"header.stamp lies {delay:.1f} s ahead (more than {STAMP_FUTURE_LIMIT_S:g} s)"
        )
    return max(delay, 0.0)


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


def trajectory_plans(
    axes: Mapping[str, Any], msg: Any, capacity: int
) -> list[tuple[Any, list[Point]]]:
    """A JointTrajectory → (axis, points) per joint named, every one checked, all or nothing.

    time_from_start counts from ``header.stamp``; each joint starts from where it is commanded
    now (a point at t = 0 is added when the first point comes later), so it never jumps.
    Positions are required for joints in csp, velocities for csv; velocities missing in csp are
    estimated (``estimated_velocities``)."""
    names = list(msg.joint_names)
    if not names:
        raise AxisRejected("the trajectory names no joint")
    if len(set(names)) != len(names):
        raise AxisRejected("the trajectory names a joint twice")
    chosen = bridge.select_axes(axes, names)
    points = list(msg.points)
    if not points:
        raise AxisRejected("the trajectory has no points")
    if capacity and len(points) > capacity - 1:
        raise AxisRejected(
            f"the trajectory has {len(points)} points; at most {capacity - 1} are taken"
        )
    times = [duration_s(p.time_from_start) for p in points]
    for i, t in enumerate(times):
        if t < 0 or (i and t <= times[i - 1]):
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
    plans = []
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
        start = _current(axis, kind)
        ts = list(times)
        if ts[0] > 0:
            ts.insert(0, 0.0)
            positions.insert(0, start[0])
            velocities.insert(0, start[1])
        if kind == "position" and any(math.isnan(v) for v in velocities):
            velocities = estimated_velocities(ts, positions)
        track = list(zip(ts, positions, velocities, strict=True))
        try:
            axis.check_trajectory(track)
        except EtherRosError as exc:
            raise AxisRejected(str(exc)) from None
        plans.append((axis, track))
    return plans


def _current(axis: Any, kind: str | None) -> tuple[float, float]:
    """(position, velocity) the axis is commanded to now: where a trajectory starts."""
    st = bridge.axis_status(axis)
    if kind == "velocity":
        return float(st["position"]), float(st["velocity"])
    enabled = st["state"] == "operation_enabled"
    return float(st["target_position"] if enabled else st["position"]), 0.0


def axis_joint_values(axes: Mapping[str, Any]) -> list[tuple[str, float, float, float]]:
    """(joint, position, velocity, effort) of every axis in SI units, for ``joint_states``."""
    out = []
    for name, axis in axes.items():
        try:
            st = bridge.axis_status(axis)
        except EtherRosError:
            continue  # the bus stopped meanwhile: the next message has them again
        out.append((name, float(st["position"]), float(st["velocity"]), float(st["torque"])))
    return out
