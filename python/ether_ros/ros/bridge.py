"""What the ROS node needs from the master's ``Bus``, in one place: the layout as
:class:`BusSpec`, the sample batches as (record, image) pairs, the joint mapping, the statistics
as flat numbers, and checked writes.

Everything else in :mod:`ether_ros.ros` talks to this module rather than to the ``Bus`` directly,
so a change in the master's API shows up here only.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from ether_ros._native import AxisPlan as EngineAxisPlan
from ether_ros._native import protocol
from ether_ros.errors import EtherRosError, MessageError
from ether_ros.master.axis import axis_blocker  # noqa: F401  (re-exported for the ROS side)
from ether_ros.master.samples import (  # noqa: F401  (re-exported for the ROS side)
    FLAG_LOST,
    FLAG_OVERRUN,
    FLAG_PANIC,
    FLAG_WATCHDOG,
    FLAG_WKC_ERROR,
)
from ether_ros.ros.layout import BusSpec, LayoutError, SlaveSpec, VariableSpec
from ether_ros.ros.values import InvalidValue, check_value, to_python


class WriteRejected(MessageError):
    """A write that names nothing on the bus or does not fit its variable."""


def variable_spec(var: Any, unique_name: bool) -> VariableSpec:
    """A :class:`VariableSpec` from the config's ``ProcessVariable``."""
    t = var.dtype
    if t.kind == "real":
        lo, hi = (-3.4028234663852886e38, 3.4028234663852886e38)
        if var.bit_length == 64:
            lo, hi = -math.inf, math.inf
    else:
        rng = var.range()
        lo, hi = (float(rng[0]), float(rng[1])) if rng is not None else (0.0, 0.0)
    return VariableSpec(
        name=var.name if unique_name else var.key,
        type=t.name,
        index=int(var.index),
        subindex=int(var.subindex),
        bit_length=int(var.bit_length),
        minimum=lo,
        maximum=hi,
    )


def slave_spec(
    name: str, position: int, device: str, layout: Any, group: tuple[str, int] = ("default", 0)
) -> SlaveSpec:
    """``group``: (slave group, its cycle in µs)."""
    if layout is None:
        return SlaveSpec(name, position, device, group=group[0], group_cycle_us=group[1])
    counts: dict[str, int] = {}
    for v in (*layout.outputs, *layout.inputs):
        counts[v.name] = counts.get(v.name, 0) + 1
    return SlaveSpec(
        name=name,
        position=position,
        device=device,
        inputs=tuple(variable_spec(v, counts[v.name] == 1) for v in layout.inputs),
        outputs=tuple(variable_spec(v, counts[v.name] == 1) for v in layout.outputs),
        group=group[0],
        group_cycle_us=group[1],
    )


def bus_spec(bus: Any) -> BusSpec:
    """The layout of an opened ``Bus``: slaves in bus order with their mapped variables."""
    slaves = []
    cycle_us = int(bus.config.bus.cycle_us)
    group_of = {
        name: (g.name, g.every * cycle_us)
        for g in (bus.layout.groups if getattr(bus, "layout", None) is not None else [])
        for name in g.slaves
    }
    for s in bus.slaves:
        device = s.device.type_name if getattr(s, "device", None) is not None else ""
        group = group_of.get(s.name, ("default", cycle_us))
        slaves.append(slave_spec(s.name, int(s.position), device, s.layout, group))
    return BusSpec(
        bus=str(bus.config.bus.name), cycle_us=int(bus.config.bus.cycle_us), slaves=tuple(slaves)
    )


@dataclass(frozen=True)
class ImageSlice:
    """Where one slave's data sits in the cyclic process image."""

    slave: str
    output_offset: int
    output_bytes: int
    input_offset: int
    input_bytes: int


def frame_masks(bus: Any) -> dict[str, int]:
    """Per slave, a bit mask of the cyclic frames that carry its process data (what a sample's
    ``stale_mask`` is checked against)."""
    frames_of = getattr(bus, "input_frames", None)
    if frames_of is None:
        return {}
    out = {}
    for s in bus.slaves:
        mask = 0
        for k in frames_of(s.name):
            mask |= 1 << k
        out[s.name] = mask
    return out


def image_slices(bus: Any) -> list[ImageSlice]:
    out = []
    for s in bus.slaves:
        a = s.area
        if a is None:
            continue
        out.append(
            ImageSlice(
                s.name,
                int(a.output_offset),
                int(a.output_bytes),
                int(a.input_offset),
                int(a.input_bytes),
            )
        )
    return out


def output_bytes(bus: Any) -> int:
    return int(bus.layout.output_bytes) if bus.layout is not None else 0


def axis_plan_entries(bus: Any) -> list[EngineAxisPlan]:
    """The running cyclic plan's ``axes`` (``_native.AxisPlan``: image offsets, scales;
    ``axis.plan_entries``) of a started bus; empty before the bus has a plan."""
    plan = getattr(bus, "plan", None)
    return list(plan.axes) if plan is not None else []


def expected_wkc(bus: Any) -> int:
    """What a sample's ``wkc`` is on a healthy bus: the expected working counters of the frames
    that go out every cycle (slave groups at a slower cycle add theirs only in their cycles)."""
    layout = getattr(bus, "layout", None)
    if layout is None:
        return 0
    return sum(f.expected_wkc for f in layout.frames if f.every == 1)


def sample_arrays(batch: Any) -> tuple[Any, Any]:
    """(records, images) of one ``Bus.samples()`` batch: a structured numpy array of records
    (``ether_ros.master.samples.SAMPLE_DTYPE``) and a 2-D uint8 array, one image per row."""
    if batch is None:
        return None, None
    records = getattr(batch, "records", None)
    if records is not None:
        return records, batch.images
    records, images = batch
    return records, images


def area_decoder(variables: Any) -> protocol.AreaDecoder:
    """A decoder of one slave's input or output area into floats, in layout order, fast enough
    for every published sample (the protocol crate's value codec, in native code). Gives the
    same values as ``ProcessLayout.unpack``."""
    return protocol.AreaDecoder([(v.bit_offset, v.bit_length, v.dtype.kind) for v in variables])


def flat_stats(stats: Mapping[str, Any], prefix: str = "") -> dict[str, float]:
    """Nested statistics -> {"wake_latency.p99": 1234.0, "lost_frames": 0.0, ...}."""
    out: dict[str, float] = {}
    for key, value in stats.items():
        name = f"{prefix}{key}"
        if isinstance(value, Mapping):
            out.update(flat_stats(value, f"{name}."))
        elif isinstance(value, bool | int | float):
            out[name] = float(value)
    return out


def stat(stats: Mapping[str, float], name: str) -> float:
    """A counter by its last name part, wherever it is nested (``counters.lost_frames``)."""
    if name in stats:
        return stats[name]
    for key, value in stats.items():
        if key.endswith("." + name):
            return value
    return 0.0


def resolve_write(
    spec: BusSpec,
    slave: str,
    position: int,
    all_slaves: bool,
    variable: str,
    value: float,
    text: str,
) -> list[tuple[SlaveSpec, VariableSpec, float]]:
    """A WriteVariable request -> the checked (slave, variable, value) writes it stands for."""
    from ether_ros.ros.values import parse_text

    for field, text_value in (("slave", slave), ("variable", variable), ("text", text)):
        problem = message_text_problem(text_value)
        if problem is not None:
            raise WriteRejected(f"{field}: {problem}", field=field)
    if not variable:
        raise WriteRejected("no variable given", field="variable")
    if all_slaves and (slave or position >= 0):
        target = f"slave {slave!r}" if slave else f"position {position}"
        raise WriteRejected(
            f"all_slaves is true and {target} is given: name one slave or all of them",
            field="all_slaves",
        )
    if all_slaves:
        targets = [s for s in spec.slaves if s.has_output(variable)]
        if not targets:
            raise WriteRejected(f"no slave has an output variable '{variable}'", field="variable")
    else:
        try:
            if slave:
                targets = [spec.slave(slave)]
            elif position >= 0:
                targets = [spec.slave(position)]
            else:
                raise WriteRejected("no slave given (name, position or all_slaves)", field="slave")
        except LayoutError as exc:
            raise WriteRejected(str(exc), field="slave" if slave else "position") from None
    out = []
    for s in targets:
        try:
            var = s.output(variable)
        except LayoutError:
            kind = "an input" if _has_input(s, variable) else "not a variable"
            raise WriteRejected(
                f"slave '{s.name}': '{variable}' is {kind} (outputs only)", field="variable"
            ) from None
        try:
            checked = parse_text(text, var) if text else check_value(value, var)
        except InvalidValue as exc:
            raise WriteRejected(
                f"slave '{s.name}': {exc}", field="text" if text else "value"
            ) from None
        out.append((s, var, checked))
    return out


#: Longest name or text a message may carry (slave, variable and joint names, text values).
MAX_MESSAGE_TEXT = 255


def message_text_problem(text: str) -> str | None:
    """Why a name or text of a ROS message is refused before it is looked up: too long, or a
    NUL or other control character (a NUL would cut the name short in C code: rclpy hands
    ``Kp100_knee\\0junk`` to Python as ``Kp100_knee``; see ``ros/native_commands.py``)."""
    if len(text) > MAX_MESSAGE_TEXT:
        return f"{len(text)} characters (at most {MAX_MESSAGE_TEXT})"
    for i, ch in enumerate(text):
        if ord(ch) < 0x20 or 0x7F <= ord(ch) < 0xA0:
            return f"character {i} is a control character ({ch!r})"
    return None


def check_joint_names(names: list[str]) -> None:
    """Joint names of a message, refused before any lookup when one is too long or holds a
    control character (:func:`message_text_problem`)."""
    for i, name in enumerate(names):
        problem = message_text_problem(name)
        if problem is not None:
            raise AxisRejected(f"joint name {i}: {problem}", field="name")


def _has_input(slave: SlaveSpec, ref: str) -> bool:
    try:
        slave.input(ref)
    except LayoutError:
        return False
    return True


def describe_writes(writes: list[tuple[SlaveSpec, VariableSpec, float]]) -> str:
    """The answer to an applied write (the native command path words it the same way)."""
    if not writes:
        return "nothing to write"
    shown = ", ".join(f"{s.name}.{v.name}={value:g}" for s, v, value in writes[:8])
    more = f" (+{len(writes) - 8} more)" if len(writes) > 8 else ""
    return f"wrote {shown}{more}"


def apply_writes(bus: Any, writes: list[tuple[SlaveSpec, VariableSpec, float]]) -> None:
    """Put checked writes into the output image with one ``write_slaves``: the master checks
    them all (also what only it can check, such as a leg's workspace against its current
    outputs) before it writes any, and they reach the wire in the same cycle."""
    by_slave: dict[str | int, dict[str, object]] = {}
    for s, var, value in writes:
        by_slave.setdefault(s.name, {})[var.name] = to_python(value, var.type)
    bus.write_slaves(by_slave)


# ---------------------------------------------------------------------------- CiA 402 axes
# The ROS side sees an axis through these functions: its joint name, its status (SI units),
# its mode and the four commands. ``Axis`` objects come from ``bus.axes()`` and live as long
# as the bus's cyclic run (the node takes them at activate).

# JointState array carrying each setpoint kind of ``Axis.command``.
JOINT_ARRAY = {"position": "position", "velocity": "velocity", "torque": "effort"}


class AxisRejected(WriteRejected):
    """An axis command (joint command, trajectory, service) refused before anything was
    written."""


def bus_axes(bus: Any) -> dict[str, Any]:
    """The bus's CiA 402 axes by joint name, in bus order (empty for a bus without axes)."""
    axes = getattr(bus, "axes", None)
    return {a.name: a for a in axes()} if axes is not None else {}


def trajectory_capacity(bus: Any) -> int:
    """Most points one axis's trajectory may have (the engine's slot size)."""
    plan = getattr(bus, "plan", None)
    return plan.trajectory_capacity if plan is not None else 0


def select_axes(axes: Mapping[str, Any], joints: list[str]) -> list[Any]:
    """The axes named (every axis when ``joints`` is empty); unknown names refused, naming
    the known joints."""
    if not axes:
        raise AxisRejected("this bus has no CiA 402 axes")
    if not joints:
        return list(axes.values())
    check_joint_names(joints)
    unknown = [j for j in joints if j not in axes]
    if unknown:
        raise AxisRejected(
            f"unknown joint(s) {', '.join(map(repr, unknown))} (joints: {', '.join(axes)})"
        )
    seen: set[str] = set()
    chosen = []
    for j in joints:
        if j not in seen:
            seen.add(j)
            chosen.append(axes[j])
    return chosen


def axis_status(axis: Any) -> dict[str, Any]:
    """The status the RT thread last published for the axis (``Axis.status()``)."""
    return dict(axis.status())


def axis_mode(axis: Any) -> str:
    return str(axis.mode)


def setpoint_kind(axis: Any) -> str | None:
    """``position``, ``velocity`` or ``torque``: what the axis's mode takes (None: homing)."""
    from ether_ros.master.axis import SETPOINT_KIND

    return SETPOINT_KIND.get(axis.mode)


# The node's AxisCommand services (joint names → one command each), by service name.
AXIS_SERVICES = ("enable", "disable", "reset_fault", "home")
# Those that change an axis's mode while they run (the native joint table holds the joints).
MODE_CHANGING = ("set_mode", "home")


def run_axis_command(axis: Any, command: str, mode: str = "") -> None:
    """``enable``, ``disable``, ``reset_fault``, ``home`` (the drive's configured homing, back
    in the axis's mode afterwards, ``Axis.home``) or ``set_mode`` on one axis; blocks until the
    drive has done it (or raises ``EtherRosError`` saying where it stuck)."""
    if command == "enable":
        axis.enable()
    elif command == "disable":
        axis.disable()
    elif command == "reset_fault":
        axis.reset_fault()
    elif command == "set_mode":
        axis.set_mode(mode)
    elif command == "home":
        axis.home()
    else:
        raise AxisRejected(f"unknown axis command {command!r}")


def resolve_joint_command(
    axes: Mapping[str, Any],
    names: list[str],
    position: list[float],
    velocity: list[float],
    effort: list[float],
) -> list[tuple[Any, str, float]]:
    """A ``joint_commands`` JointState → the checked (axis, kind, value) setpoints it stands
    for, all or nothing.

    Any subset of the joints, by name. An array is empty (not given) or has one value per name;
    each joint takes the value of the array its mode takes (position for csp/pp, velocity for
    csv/pv, effort for cst), which must be a finite number within the joint's limits. A value
    in another array is ignored when the mode's is there (``topic_based_ros2_control`` may send
    several), and refused as the wrong kind when it is the only one."""
    if not axes:
        raise AxisRejected("this bus has no CiA 402 axes")
    if not names:
        raise AxisRejected("no joint names", field="name")
    check_joint_names(names)
    arrays = {"position": position, "velocity": velocity, "effort": effort}
    for label, values in arrays.items():
        if len(values) not in (0, len(names)):
            raise AxisRejected(
                f"{label} has {len(values)} value(s) for {len(names)} joint name(s) "
                "(give one per name, or none)",
                field=label,
            )
    out = []
    seen: set[str] = set()
    for i, name in enumerate(names):
        if name in seen:
            raise AxisRejected(f"joint {name!r} is named twice", field="name")
        seen.add(name)
        axis = axes.get(name)
        if axis is None:
            raise AxisRejected(f"unknown joint {name!r} (joints: {', '.join(axes)})", field="name")
        kind = setpoint_kind(axis)
        if kind is None:
            raise AxisRejected(
                f"joint {name!r} is in mode {axis.mode}: it takes no setpoint", field="name"
            )
        values = arrays[JOINT_ARRAY[kind]]
        value = float(values[i]) if values else math.nan
        if not math.isfinite(value):
            others = [k for k, v in arrays.items() if v and math.isfinite(v[i])]
            if others and not values:
                raise AxisRejected(
                    f"joint {name!r} is in mode {axis.mode}: it takes a {JOINT_ARRAY[kind]}, "
                    f"got {' and '.join(others)}",
                    field=JOINT_ARRAY[kind],
                )
            raise AxisRejected(
                f"joint {name!r}: {JOINT_ARRAY[kind]} {value!r} is not a finite number"
                if values
                else f"joint {name!r}: no {JOINT_ARRAY[kind]} given (mode {axis.mode})",
                field=JOINT_ARRAY[kind],
            )
        try:
            axis.check_command(kind, value)
        except EtherRosError as exc:
            raise AxisRejected(str(exc), field=JOINT_ARRAY[kind]) from None
        out.append((axis, kind, value))
    return out


def apply_joint_commands(commands: list[tuple[Any, str, float]]) -> None:
    """Write checked setpoints into the axes' command slots."""
    for axis, kind, value in commands:
        axis.command(**{kind: value})


def describe_joint_commands(commands: list[tuple[Any, str, float]]) -> str:
    shown = ", ".join(f"{a.name} {k}={v:g}" for a, k, v in commands[:8])
    more = f" (+{len(commands) - 8} more)" if len(commands) > 8 else ""
    return f"commanded {shown}{more}"


def follow_plan(plan: Any) -> int:
    """Start a checked ``joints.TrajectoryPlan``: one hand-over to the engine, every axis starts
    in the same cycle, times from ``plan.start_ns``. Returns the command's number."""
    from ether_ros.master.axis import TrajectoryPoint, hand_over

    if not plan.tracks:
        return 0
    bus = plan.tracks[0][0].bus
    return hand_over(
        bus, {axis: [TrajectoryPoint(*p) for p in track] for axis, track in plan.tracks},
        plan.start_ns,
    )  # fmt: skip


def trajectory_stop_reason(
    axes: Sequence[Any], statuses: Sequence[Mapping[str, Any]]
) -> str | None:
    """Why the trajectory last handed to ``axes`` cannot go on, from their statuses just read,
    or None while it can (``Axis.own_stop_reason``: mode change, disable, fault, quick stop,
    panic, watchdog). A joint's own reason comes before "stopped with its trajectory", which
    only says that another joint of it left it."""
    from ether_ros.master.axis import stopped_with_trajectory

    if not axes:
        return None
    panicked = bool(axes[0].bus.engine.is_panicked)
    for axis, st in zip(axes, statuses, strict=True):
        why = axis.own_stop_reason(st, panicked)
        if why is not None:
            return why
    for axis, st in zip(axes, statuses, strict=True):
        if axis.stopped_with_trajectory(st):
            return stopped_with_trajectory(axis.name)
    return None


def engine_now_ns(axes: Mapping[str, Any]) -> int:
    """The engine clock (CLOCK_MONOTONIC ns) of the bus the axes are on."""
    axis = next(iter(axes.values()))
    return int(axis.bus.engine.now_ns())


def quiet_stop(axes: list[Any]) -> None:
    """A quiet stop (``Axis.quiet_stop``) on every axis given, in the same cycle."""
    if axes:
        axes[0].bus.quiet_stop([a.name for a in axes])


def check_mode(axes: list[Any], mode: str) -> None:
    """Refuse a mode before any axis is switched: unknown, or not offered by one of the
    drives."""
    from ether_ros.config.cia402 import MODES

    if mode not in MODES:
        raise AxisRejected(f"unknown mode {mode!r} (modes: {', '.join(MODES)})")
    for axis in axes:
        if mode not in axis.spec.modes:
            raise AxisRejected(
                f"joint {axis.name!r}: the drive does not offer mode {mode} "
                f"(it offers {', '.join(axis.spec.modes)})"
            )


def joint_rows(axes: Mapping[str, Any]) -> list[tuple[str, int, float, float, float, float, Any]]:
    """Each axis as the native joint table takes it: (joint, engine axis index, position
    limits, velocity limit, torque limit, the setpoint kind its mode takes)."""
    rows = []
    for name, axis in axes.items():
        c = axis.spec.config
        lo, hi = c.position_limits
        rows.append(
            (
                name,
                int(axis.index),
                float(lo),
                float(hi),
                float(c.velocity_limit),
                float(c.torque_limit),
                setpoint_kind(axis),
            )
        )
    return rows


def stop_motion(bus: Any) -> None:
    """Every axis to its ``on_stop``, every slave's outputs to their safe values (as commands;
    the cyclic exchange goes on): what a lapsed control lease does."""
    if bus is not None and getattr(bus, "running", False):
        bus.stop_motion()
