"""The console's command language: a pure parser from one line of text to a checked command.

Nothing here talks to ROS or to the bus. :func:`parse_command` gets the line and a
:class:`ConsoleContext` (the bus layout the node published and the output values last seen) and
returns a command object, or raises :class:`CommandError` with a message saying what is wrong —
in which case nothing is sent. Writes are validated against the ESI type and range of every
variable and, for a Laelaps II leg, against the leg workspace, so a command the firmware would
silently disregard is refused with its reason.

Grammar (words separated by blanks; quotes group words, nothing is ever run by a shell)::

    start | stop | restart | panic | clear
    set TARGET VAR=VALUE [VAR=VALUE ...]     TARGET: slave name, position, or "all"
    set TARGET VAR VALUE                     VAR: name or index:subindex ("0x7030:04")
    get SLAVE [VAR]
    states | stats | layout [SLAVE]
    sdo read SLAVE INDEX:SUB TYPE
    sdo write SLAVE INDEX:SUB TYPE VALUE
    enable | disable | reset_fault [JOINT ...|all]   CiA 402 axes (none or "all": every axis)
    set_mode JOINT|all MODE                  MODE: csp csv cst pp pv hm
    move JOINT VALUE                         one setpoint, SI units, of the kind the mode takes
    run FILE [step]                          a sequence file (see ether_ros.console.sequence)
    lease [take|release]                     the control lease: who holds it; take it over
    wait SECONDS
    help [COMMAND] | quit | exit
"""

from __future__ import annotations

import math
import shlex
from collections.abc import Mapping
from dataclasses import dataclass, field, replace

from ether_ros._native.protocol import format_address
from ether_ros.config.cia402 import MODES
from ether_ros.errors import EtherRosError
from ether_ros.master import workspace
from ether_ros.master.axis import SETPOINT_KIND
from ether_ros.ros.layout import BusSpec, LayoutError, SlaveSpec, VariableSpec, parse_address
from ether_ros.ros.values import InvalidValue, parse_text, type_range


class CommandError(EtherRosError):
    """An invalid console command: the message says why; nothing was sent."""


CONTROL_COMMANDS = {
    "start": "start",
    "stop": "stop",
    "restart": "restart",
    "panic": "panic",
    "clear": "clear_panic",
    "clear_panic": "clear_panic",
}

HELP: dict[str, str] = {
    "start": "start                      bring the bus to OP and start the cyclic exchange",
    "stop": "stop                       safe outputs, bus to SAFEOP",
    "restart": "restart                    stop, then start",
    "panic": "panic                      safe outputs on the wire now (also: Ctrl-P or F1)",
    "clear": "clear                      clear a panic (outputs stay safe until commanded again)",
    "set": "set TARGET VAR=VALUE ...   write outputs; TARGET is a slave, a position or 'all'",
    "get": "get SLAVE [VAR]            latest input and output values",
    "states": "states                     lifecycle state and each slave's AL state",
    "stats": "stats                      loop timing, lost frames, DC error",
    "layout": "layout [SLAVE]             variables, types and ranges",
    "sdo": "sdo read|write SLAVE INDEX:SUB TYPE [VALUE]   CoE object access",
    "run": "run FILE [step]            run a sequence file (step: confirm each step)",
    "wait": "wait SECONDS               pause (in sequences)",
    "enable": "enable [JOINT ...|all]      CiA 402 axes to Operation Enabled (none: all)",
    "disable": "disable [JOINT ...|all]     the axes' on_stop (quick stop or disable voltage)",
    "reset_fault": "reset_fault [JOINT ...|all] fault reset of the axes",
    "set_mode": "set_mode JOINT|all MODE     mode of operation (csp csv cst pp pv hm)",
    "move": "move JOINT VALUE           one setpoint (SI units) of the kind the joint's mode takes",
    "lease": "lease [take|release]       who holds the control lease; take it over; give it back",
    "help": "help [COMMAND]             this text",
    "quit": "quit                       leave the console (the node keeps running)",
}


@dataclass(frozen=True)
class Control:
    """start / stop / restart / panic / clear_panic."""

    command: str


@dataclass(frozen=True)
class WriteOp:
    slave: str
    variable: str
    value: float


@dataclass(frozen=True)
class Write:
    ops: tuple[WriteOp, ...]


@dataclass(frozen=True)
class Get:
    slave: str
    variable: str | None = None


@dataclass(frozen=True)
class Show:
    what: str  # states | stats | layout
    slave: str | None = None


@dataclass(frozen=True)
class SdoRead:
    slave: str
    index: int
    subindex: int
    type: str


@dataclass(frozen=True)
class SdoWrite:
    slave: str
    index: int
    subindex: int
    type: str
    value: str


@dataclass(frozen=True)
class RunSequence:
    path: str
    step: bool = False


@dataclass(frozen=True)
class Wait:
    seconds: float


@dataclass(frozen=True)
class JointLimits:
    """A CiA 402 axis as the console checks commands for it: its mode (as last reported) and
    its limits (SI units)."""

    mode: str
    position_limits: tuple[float, float]
    velocity_limit: float
    torque_limit: float


@dataclass(frozen=True)
class AxisOp:
    """enable / disable / reset_fault for joints (empty: every axis)."""

    command: str
    joints: tuple[str, ...] = ()


@dataclass(frozen=True)
class SetMode:
    mode: str
    joints: tuple[str, ...] = ()


@dataclass(frozen=True)
class Move:
    """One setpoint on ``joint_commands``: ``array`` is the JointState array (position,
    velocity or effort) the joint's mode takes."""

    joint: str
    array: str
    value: float


@dataclass(frozen=True)
class LeaseOp:
    """The control lease: ``status`` (who holds it), ``take`` (take it over from whoever holds
    it: the operator's right) or ``release``."""

    action: str


@dataclass(frozen=True)
class Help:
    topic: str | None = None


@dataclass(frozen=True)
class Quit:
    pass


Command = (
    Control
    | Write
    | Get
    | Show
    | SdoRead
    | SdoWrite
    | RunSequence
    | Wait
    | AxisOp
    | SetMode
    | Move
    | LeaseOp
    | Help
    | Quit
)


@dataclass
class ConsoleContext:
    """What the parser knows about the bus: the layout and the output values last seen (raw
    values by slave and variable name), to check a write against the rest of a leg's
    trajectory."""

    layout: BusSpec | None
    outputs: dict[str, dict[str, float]] = field(default_factory=dict)
    # CiA 402 axes by joint name (from the node's axes.* parameters and axis diagnostics).
    joints: dict[str, JointLimits] = field(default_factory=dict)

    def cleared(self) -> ConsoleContext:
        """The context after a clear_panic: no output value known (the node reset them to
        their safe values)."""
        return replace(self, outputs={})

    def after(self, write: Write) -> ConsoleContext:
        """The context as it will be once ``write`` is applied (for checking sequences)."""
        outputs = {slave: dict(values) for slave, values in self.outputs.items()}
        for op in write.ops:
            outputs.setdefault(op.slave, {})[op.variable] = op.value
        return replace(self, outputs=outputs)


def parse_command(line: str, ctx: ConsoleContext) -> Command | None:
    """Parse one line. Blank lines and ``#`` comments give None. Raises :class:`CommandError`."""
    try:
        words = shlex.split(line, comments=True)
    except ValueError as exc:
        raise CommandError(f"cannot split the line into words: {exc}") from None
    if not words:
        return None
    head, args = words[0].lower(), words[1:]
    if head in CONTROL_COMMANDS:
        _no_args(head, args)
        return Control(CONTROL_COMMANDS[head])
    if head == "set":
        return _parse_set(args, ctx)
    if head == "get":
        if not 1 <= len(args) <= 2:
            raise CommandError("usage: get SLAVE [VAR]")
        slave = _slave(ctx, args[0])
        variable = None
        if len(args) == 2:
            variable = _any_variable(slave, args[1]).name
        return Get(slave.name, variable)
    if head in ("states", "stats"):
        _no_args(head, args)
        return Show(head)
    if head == "layout":
        if len(args) > 1:
            raise CommandError("usage: layout [SLAVE]")
        return Show("layout", _slave(ctx, args[0]).name if args else None)
    if head == "sdo":
        return _parse_sdo(args, ctx)
    if head in ("enable", "disable", "reset_fault"):
        return AxisOp(head, _joints(ctx, args))
    if head == "set_mode":
        if len(args) != 2:
            raise CommandError("usage: set_mode JOINT|all MODE")
        return _parse_set_mode(args[0], args[1].lower(), ctx)
    if head == "move":
        if len(args) != 2:
            raise CommandError("usage: move JOINT VALUE")
        return _parse_move(args[0], args[1], ctx)
    if head == "run":
        if not args or len(args) > 2 or (len(args) == 2 and args[1] != "step"):
            raise CommandError("usage: run FILE [step]")
        return RunSequence(args[0], step=len(args) == 2)
    if head == "wait":
        if len(args) != 1:
            raise CommandError("usage: wait SECONDS")
        return Wait(_seconds(args[0]))
    if head == "lease":
        if len(args) > 1 or (args and args[0].lower() not in ("take", "release", "status")):
            raise CommandError("usage: lease [take|release]")
        return LeaseOp(args[0].lower() if args else "status")
    if head in ("help", "?"):
        if len(args) > 1:
            raise CommandError("usage: help [COMMAND]")
        if args and args[0] not in HELP:
            raise CommandError(f"no command '{args[0]}'; try 'help'")
        return Help(args[0] if args else None)
    if head in ("quit", "exit"):
        _no_args(head, args)
        return Quit()
    raise CommandError(f"unknown command '{words[0]}'; try 'help'")


def help_text(topic: str | None = None) -> str:
    if topic is not None:
        return HELP[topic]
    return "\n".join(HELP.values())


def _no_args(head: str, args: list[str]) -> None:
    if args:
        raise CommandError(f"'{head}' takes no arguments (got '{' '.join(args)}')")


def _seconds(text: str) -> float:
    try:
        seconds = float(text)
    except ValueError:
        raise CommandError(f"'{text}' is not a number of seconds") from None
    if not math.isfinite(seconds) or seconds < 0:
        raise CommandError(f"wait needs a non-negative number of seconds, not '{text}'")
    return seconds


def _layout(ctx: ConsoleContext) -> BusSpec:
    if ctx.layout is None:
        raise CommandError("the bus layout is not known yet (is the node configured?)")
    return ctx.layout


def _slave(ctx: ConsoleContext, ref: str) -> SlaveSpec:
    try:
        return _layout(ctx).slave(ref)
    except LayoutError as exc:
        raise CommandError(str(exc)) from None


def _any_variable(slave: SlaveSpec, ref: str) -> VariableSpec:
    for find in (slave.output, slave.input):
        try:
            return find(ref)
        except LayoutError:
            continue
    raise CommandError(f"slave '{slave.name}' has no variable '{ref}'")


def _parse_set(args: list[str], ctx: ConsoleContext) -> Write:
    usage = "usage: set TARGET VAR=VALUE [VAR=VALUE ...]  or  set TARGET VAR VALUE"
    if len(args) < 2:
        raise CommandError(usage)
    target, rest = args[0], args[1:]
    if len(rest) == 2 and "=" not in rest[0] and "=" not in rest[1]:
        pairs = [(rest[0], rest[1])]
    else:
        pairs = []
        for word in rest:
            name, sep, text = word.partition("=")
            if not sep or not name or not text:
                raise CommandError(f"'{word}' is not VAR=VALUE; {usage}")
            pairs.append((name, text))
    layout = _layout(ctx)
    if target.lower() == "all":
        slaves = [s for s in layout.slaves if all(s.has_output(name) for name, _ in pairs)]
        if not slaves:
            names = ", ".join(name for name, _ in pairs)
            raise CommandError(f"no slave has the output variable(s) {names}")
    else:
        slaves = [_slave(ctx, target)]
    ops: list[WriteOp] = []
    for slave in slaves:
        assigned: dict[str, float] = {}
        for name, text in pairs:
            try:
                var = slave.output(name)
            except LayoutError as exc:
                if _is_input(slave, name):
                    raise CommandError(
                        f"'{name}' is an input of slave '{slave.name}'; only outputs can be set"
                    ) from None
                raise CommandError(str(exc)) from None
            try:
                value = parse_text(text, var)
            except InvalidValue as exc:
                raise CommandError(f"slave '{slave.name}': {exc}") from None
            if var.name in assigned:
                raise CommandError(f"{var.name} is assigned twice")
            assigned[var.name] = value
            ops.append(WriteOp(slave.name, var.name, value))
        _check_leg_workspace(slave, assigned, ctx)
    return Write(tuple(ops))


def _is_input(slave: SlaveSpec, ref: str) -> bool:
    try:
        slave.input(ref)
    except LayoutError:
        return False
    return True


def _outputs(slave: SlaveSpec) -> list[tuple[str, int, int]]:
    return [(v.name, v.index, v.subindex) for v in slave.outputs]


def is_laelaps_leg(slave: SlaveSpec) -> bool:
    """A Laelaps II leg: its device says so and it maps the trajectory record 0x7030."""
    return workspace.is_laelaps_leg(slave.device, _outputs(slave))


def _check_leg_workspace(
    slave: SlaveSpec, assigned: Mapping[str, float], ctx: ConsoleContext
) -> None:
    """The master's rule (:func:`ether_ros.master.workspace.leg_write_problem`) on the
    console's view of the outputs, so a sequence file is checked step by step before its first
    step is sent; the master checks every write again against the outputs it holds."""
    outputs = _outputs(slave)
    names = workspace.ruled_outputs(slave.device, outputs)
    if not any(name in names for name in assigned):
        return
    current = ctx.outputs.get(slave.name, {})
    unknown = next((name for name in names if name not in assigned and name not in current), None)
    if unknown is not None:
        raise CommandError(
            f"slave '{slave.name}': cannot check the leg workspace, the current value of "
            f"{unknown} is not known yet (no outputs received from the node)"
        )
    problem = workspace.leg_write_problem(slave.device, outputs, current, assigned)
    if problem is not None:
        raise CommandError(f"slave '{slave.name}': {problem}")


def _known_joints(ctx: ConsoleContext) -> dict[str, JointLimits]:
    if not ctx.joints:
        raise CommandError("no CiA 402 axes known (the bus has none, or the node is not up yet)")
    return ctx.joints


def _joints(ctx: ConsoleContext, args: list[str]) -> tuple[str, ...]:
    """Joint names (none or "all": every axis), each one checked."""
    joints = _known_joints(ctx)
    if not args or (len(args) == 1 and args[0].lower() == "all"):
        return ()
    for name in args:
        if name not in joints:
            raise CommandError(f"unknown joint '{name}' (joints: {', '.join(joints)})")
    if len(set(args)) != len(args):
        raise CommandError("a joint is named twice")
    return tuple(args)


def _parse_set_mode(target: str, mode: str, ctx: ConsoleContext) -> SetMode:
    joints = _joints(ctx, [target])
    if mode not in MODES:
        raise CommandError(f"unknown mode '{mode}' (modes: {', '.join(MODES)})")
    return SetMode(mode, joints)


def _parse_move(joint: str, text: str, ctx: ConsoleContext) -> Move:
    (name,) = _joints(ctx, [joint]) or ("all",)
    if name == "all":
        raise CommandError("move takes one joint (not all)")
    limits = ctx.joints[name]
    kind = SETPOINT_KIND.get(limits.mode)
    if kind is None:
        raise CommandError(f"joint '{name}' is in mode {limits.mode}: it takes no setpoint")
    try:
        value = float(text)
    except ValueError:
        raise CommandError(f"'{text}' is not a number") from None
    if not math.isfinite(value):
        raise CommandError(f"joint '{name}': {kind} {text} is not a finite number")
    if kind == "position":
        lo, hi = limits.position_limits
        if not lo <= value <= hi:
            raise CommandError(
                f"joint '{name}': position {value:g} is outside the limits [{lo:g}, {hi:g}]"
            )
    else:
        limit = limits.velocity_limit if kind == "velocity" else limits.torque_limit
        if abs(value) > limit:
            raise CommandError(f"joint '{name}': {kind} {value:g} is beyond the limit ±{limit:g}")
    return Move(name, "effort" if kind == "torque" else kind, value)


def _parse_sdo(args: list[str], ctx: ConsoleContext) -> SdoRead | SdoWrite:
    usage = "usage: sdo read SLAVE INDEX:SUB TYPE  |  sdo write SLAVE INDEX:SUB TYPE VALUE"
    if not args or args[0] not in ("read", "write"):
        raise CommandError(usage)
    op = args[0]
    if (op == "read" and len(args) != 4) or (op == "write" and len(args) != 5):
        raise CommandError(usage)
    slave = _slave(ctx, args[1])
    try:
        address = parse_address(args[2])
    except LayoutError as exc:
        raise CommandError(str(exc)) from None
    if address is None:
        raise CommandError(f"'{args[2]}' is not an object address INDEX:SUB (e.g. 0x8000:01)")
    type_name = args[3].upper()
    try:
        type_range(type_name)
    except InvalidValue as exc:
        raise CommandError(str(exc)) from None
    if op == "read":
        return SdoRead(slave.name, address[0], address[1], type_name)
    lo, hi = type_range(type_name)
    probe = VariableSpec(format_address(*address), type_name, *address, 0, lo, hi)
    try:
        parse_text(args[4], probe)
    except InvalidValue as exc:
        raise CommandError(str(exc)) from None
    return SdoWrite(slave.name, address[0], address[1], type_name, args[4])
