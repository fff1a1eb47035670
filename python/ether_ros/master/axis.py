"""CiA 402 drives as joints: ``bus.axis(name)`` → :class:`Axis` (docs/cia402.md).

The engine's axis stage runs the drive's state machine, the targets and the stop on its RT
thread; this module turns the configured axes into plan entries and checks commands before
they reach the engine's lock-free command slot (``Engine.axis_*``, callable without Python by a
native thread). A refused command raises :class:`AxisCommandError` and writes nothing.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from ether_ros import _native
from ether_ros._native.protocol import emergency_text
from ether_ros.config.cia402 import (
    AXIS_STRIDE,
    HOMING_OBJECTS,
    MODES,
    PROFILE_OBJECTS,
    SUPPORTED_HOMING_METHODS,
    AxisSpec,
    acceleration_limit,
    profile_raw,
)
from ether_ros.config.process import ProcessValueError
from ether_ros.errors import BusError

if TYPE_CHECKING:
    from ether_ros.master.bus import Bus
    from ether_ros.master.plan import ImageLayout

# Setpoint kind per mode (None: homing takes no setpoint).
SETPOINT_KIND = {"csp": "position", "pp": "position", "csv": "velocity", "pv": "velocity",
                 "cst": "torque", "hm": None}  # fmt: skip
POLL_S = 0.002


class AxisError(BusError):
    """An axis did not do what was asked (never reached Operation Enabled, fault)."""


class AxisCommandError(AxisError, ValueError):
    """A command refused before anything was written (bad value, mode, state)."""


class TrajectoryStopped(AxisError):
    """A trajectory ended before its end because an axis of it left the state it needs (mode
    change, disable, fault, quick stop, panic, watchdog): ``reason`` says which and what."""

    def __init__(self, reason: str) -> None:
        super().__init__(f"trajectory stopped: {reason}")
        self.reason = reason


@dataclass(frozen=True)
class TrajectoryStart:
    """A trajectory as handed to one axis: its command number, the mode the axis ran it in and
    the axis's fault count then (a fault reset automatically since still ended it)."""

    seq: int
    mode: str
    faults: int


def trajectory_stop_reason(
    name: str,
    mode: str,
    current_mode: str,
    st: Mapping[str, Any],
    panicked: bool,
    faults_before: int | None = None,
) -> str | None:
    """Why axis ``name`` cannot go on with a trajectory given to it in ``mode``, from its
    status ``st`` (``Axis.status()``), the mode now commanded, whether the bus is in panic and
    the fault count when the trajectory was handed over; None while it can. Each of these ends
    the trajectory in the engine (which stops the other axes of it quietly, docs/cia402.md
    "Trajectories"), so reporting it at once is no guess."""
    state = str(st["state"])
    if st["halted"]:
        # The engine forces the stop on every axis of the bus (panic) or of a frame (watchdog).
        return f"panic (joint {name!r} stopped)" if panicked else (
            f"watchdog stop (joint {name!r}: no command within the watchdog time)")  # fmt: skip
    faulted = faults_before is not None and int(st["faults"]) > faults_before
    if state in ("fault", "fault_reaction_active") or faulted:
        # A fault the drive was reset from already (fault_reset: auto) still ended it.
        code = int(st["error_code"]) or int(st["last_fault_code"])
        return f"joint {name!r} fault 0x{code:04X} ({emergency_text(code)})"
    if current_mode != mode:
        return f"joint {name!r} left {mode} (now {current_mode})"
    if not st["enable_wanted"]:
        return f"joint {name!r} disabled"
    if state == "quick_stop_active":
        return f"joint {name!r} quick stop"
    if state != "operation_enabled":
        return f"joint {name!r} left operation_enabled (now {state})"
    if not st["mode_reached"]:
        return f"joint {name!r} left {mode} (the drive shows {st['mode_display']})"
    return None


def stopped_with_trajectory(name: str) -> str:
    """The reason when only the engine's flag ``trajectory_stopped`` tells: another axis of
    the trajectory left it (its own reason is found on that axis while it lasts), or this one
    did for a moment too short to be seen."""
    return f"joint {name!r} stopped with its trajectory (another joint of it left it)"


@dataclass(frozen=True)
class TrajectoryPoint:
    """``t`` seconds after the trajectory's start; position (SI) and velocity (SI/s)."""

    t: float
    position: float = 0.0
    velocity: float = 0.0


def plan_entries(specs: Sequence[AxisSpec], layout: ImageLayout) -> list[_native.AxisPlan]:
    """The engine plan's ``axes``: each axis's objects as image byte offsets, its scales,
    limits and policies (every value from the configuration, whose models hold the defaults)."""
    entries: list[_native.AxisPlan] = []
    for spec in specs:
        area = layout.area(spec.slave)
        offsets: dict[str, int] = {}
        for role, var in spec.variables.items():
            base = area.output_offset if var.direction == "output" else area.input_offset
            offsets[role] = base + var.bit_offset // 8
        c = spec.config
        entries.append(
            _native.AxisPlan(
                name=c.name,
                # The roles are AxisMap's keywords: an unknown one is refused there by name.
                map=_native.AxisMap(**offsets),
                mode=c.mode,
                position_scale=c.position_scale,
                position_offset=c.position_offset,
                velocity_scale=c.velocity_scale,
                torque_scale=c.torque_scale,
                position_min=c.position_limits[0],
                position_max=c.position_limits[1],
                velocity_max=c.velocity_limit,
                torque_max=c.torque_limit,
                following_error_window=c.following_error_window,
                deceleration=c.deceleration,
                max_acceleration=acceleration_limit(c),
                mode_change_velocity=c.mode_change_velocity,
                restart=c.restart,
                on_stop=c.on_stop,
                fault_reset=c.fault_reset,
                fault_retries=c.fault_retries,
                fault_backoff_ns=round(c.fault_backoff_ms * 1e6),
            )
        )
    return entries


def output_bits(specs: Sequence[AxisSpec], layout: ImageLayout) -> dict[int, str]:
    """Image byte → axis name for every output byte an axis owns (the engine writes them each
    cycle, so the Bus refuses variable writes there)."""
    owned: dict[int, str] = {}
    for spec in specs:
        area = layout.area(spec.slave)
        for var in spec.variables.values():
            if var.direction == "output":
                start = area.output_offset + var.bit_offset // 8
                for b in range(start, start + var.bit_length // 8):
                    owned[b] = spec.name
    return owned


def follow_together(
    bus: Bus,
    tracks: Mapping[Axis, Iterable[TrajectoryPoint | tuple[float, ...]]],
    start_in: float = 0.0,
) -> float:
    """Hand the trajectories of several axes to the engine at once (one command number, one
    start time): the engine starts them in the same cycle. Checked first, all or nothing.
    Returns the start time (engine clock, s)."""
    if not tracks:
        raise AxisCommandError("a trajectory names no axis")
    checked = {axis: axis.check_trajectory(points) for axis, points in tracks.items()}
    if not math.isfinite(start_in) or start_in < 0:
        raise AxisCommandError("start_in must be >= 0 s")
    start_ns = int(bus.engine.now_ns() + start_in * 1e9)
    hand_over(bus, checked, start_ns)
    return start_ns / 1e9


def hand_over(bus: Bus, checked: Mapping[Axis, Sequence[TrajectoryPoint]], start_ns: int) -> int:
    """Give checked trajectories (``Axis.check_trajectory``) to the engine in one hand-over,
    times from ``start_ns`` on its clock (a start in the past: the engine trims the points
    already past). Returns the command's number (``status()['command_seq']`` once taken)."""
    for axis in checked:
        axis.require_running()
        axis.require_enabled("a trajectory")
    faults_before = [int(axis.status()["faults"]) for axis in checked]
    try:
        seq = int(
            bus.engine.axis_follow_many(
                start_ns,
                [
                    (axis.index, [(round(p.t * 1e9), p.position, p.velocity) for p in points])
                    for axis, points in checked.items()
                ],
            )
        )
    except ValueError as exc:
        names = ", ".join(a.name for a in checked)
        raise AxisCommandError(f"axes {names}: {exc}") from None
    for axis, faults in zip(checked, faults_before, strict=True):
        bus.axis_trajectories[axis.index] = seq
        bus.axis_trajectory_starts[axis.index] = TrajectoryStart(seq, axis.mode, faults)
    return seq


class Axis:
    """One joint on a CiA 402 drive. Units are SI (rad or m, /s, N·m or N)."""

    def __init__(self, bus: Bus, index: int, spec: AxisSpec) -> None:
        self._bus = bus
        self._index = index
        self.spec = spec

    def __repr__(self) -> str:
        return f"Axis({self.name!r}, slave {self.spec.slave!r}, axis {self.spec.axis_index + 1})"

    def __eq__(self, other: object) -> bool:
        return isinstance(other, Axis) and other.bus is self._bus and other.index == self._index

    def __hash__(self) -> int:
        return hash((id(self._bus), self._index))

    @property
    def name(self) -> str:
        return self.spec.name

    @property
    def bus(self) -> Bus:
        """The bus the axis is on."""
        return self._bus

    @property
    def index(self) -> int:
        """The axis's index in the engine (its ``axis`` argument of ``Engine.axis_*``)."""
        return self._index

    @property
    def mode(self) -> str:
        """The mode last commanded (the drive shows it in ``status()['mode_display']``); the
        same for every ``Axis`` object of this axis on the bus."""
        return self._bus.axis_modes.get(self._index, self.spec.config.mode)

    # ------------------------------------------------------------------------ status
    def status(self) -> dict[str, Any]:
        """Everything the RT thread published about the axis this cycle."""
        self.require_running()
        return dict(self._bus.engine.axis_status(self._index))

    @property
    def state(self) -> str:
        """The CiA 402 state name (``operation_enabled``, ``fault``, ...)."""
        return str(self.status()["state"])

    @property
    def position(self) -> float:
        return float(self.status()["position"])

    @property
    def velocity(self) -> float:
        return float(self.status()["velocity"])

    @property
    def torque(self) -> float:
        return float(self.status()["torque"])

    @property
    def error_code(self) -> int:
        return int(self.status()["error_code"])

    @property
    def following_error(self) -> float:
        return float(self.status()["following_error"])

    # ------------------------------------------------------------------------ power
    def enable(self, timeout: float = 2.0) -> None:
        """Fault reset if needed, shutdown, switch on, enable operation; returns once the drive
        is in Operation Enabled in the commanded mode. This is the explicit enable a blocked
        restart waits for (``restart: manual``, docs/cia402.md "Deliberate restart"); given
        while the bus is in panic it does not count (clear the panic first). Raises
        :class:`AxisError` naming the state it stuck in and its error code after ``timeout``
        seconds (or at once when a fault will not be reset, or the bus is in panic), never
        hangs."""
        self.require_running()
        engine = self._bus.engine
        st = self.status()
        if engine.is_panicked:
            raise AxisError(f"axis {self.name}: the bus is in panic (clear_panic first, then "
                            "enable)")  # fmt: skip
        if st["state"] in ("fault", "fault_reaction_active"):
            engine.axis_reset_fault(self._index)
        engine.axis_enable(self._index, True)
        deadline = time.monotonic() + timeout
        while True:
            st = self.status()
            if st["state"] == "operation_enabled" and st["mode_reached"]:
                return
            # The automatic reset gave up: waiting longer changes nothing.
            if st["retries_exhausted"] or time.monotonic() > deadline:
                break
            if engine.is_panicked:
                raise AxisError(f"axis {self.name}: the bus is in panic (clear_panic first, "
                                "then enable)")  # fmt: skip
            self._bus.feed_watchdog()
            time.sleep(POLL_S)
        raise AxisError(
            f"axis {self.name}: no operation_enabled within {timeout:g} s: stuck in "
            f"{st['state']} (statusword 0x{st['statusword']:04X}, error code "
            f"0x{st['error_code']:04X}, last fault 0x{st['last_fault_code']:04X}, mode display "
            f"{st['mode_display']})"
        )

    def disable(self, timeout: float = 1.0) -> None:
        """The configured stop (``on_stop``: quick stop or disable voltage); returns once the
        drive has left Operation Enabled."""
        self.require_running()
        self._bus.engine.axis_enable(self._index, False)
        self._wait(
            lambda st: st["state"] != "operation_enabled", timeout, "leave operation_enabled"
        )

    def reset_fault(self) -> None:
        """A rising edge of controlword bit 7 while the drive is in Fault (also gives the
        automatic reset its retries back). It does not enable the axis: with ``restart:
        manual`` call :meth:`enable` afterwards (``restart: auto`` re-enables an axis that is
        wanted enabled and inside its limits)."""
        self.require_running()
        self._bus.engine.axis_reset_fault(self._index)

    def set_mode(self, mode: str, timeout: float = 1.0) -> None:
        """Command a mode of operation (0x6060) and return once 0x6061 shows it and the axis is
        inside its position limits (and not in Fault). The csp, csv, cst, pp and pv modes switch
        at any speed, also while enabled: the new mode starts from the actual state (position
        from the actual position, velocity from the actual velocity or zero, torque from zero;
        docs/cia402.md, "Mode changes"). To or from hm only at standstill or while disabled.
        Raises :class:`AxisError` naming what the axis did instead (never a hang)."""
        self.require_running()
        if mode not in MODES:
            raise AxisCommandError(f"axis {self.name}: unknown mode {mode!r} (modes: "
                                   f"{', '.join(MODES)})")  # fmt: skip
        if mode not in self.spec.modes:
            raise AxisCommandError(f"axis {self.name}: the drive does not offer mode {mode} "
                                   f"(it offers {', '.join(self.spec.modes)})")  # fmt: skip
        target = {"position": "target_position", "velocity": "target_velocity",
                  "torque": "target_torque"}.get(SETPOINT_KIND[mode] or "")  # fmt: skip
        if target is not None and target not in self.spec.variables:
            raise AxisCommandError(f"axis {self.name}: mode {mode} needs {target}, which the "
                                   "PDOs do not map")  # fmt: skip
        if mode != self.mode and "mode" not in self.spec.variables:
            raise AxisCommandError(f"axis {self.name}: 0x6060 is not in the PDOs; the mode "
                                   f"({self.mode}) is set once in PREOP")  # fmt: skip
        homing_change = "hm" in (mode, self.mode) and mode != self.mode
        st = self.status()
        if homing_change and st["state"] == "operation_enabled" and not st["idle"]:
            raise AxisCommandError(f"axis {self.name}: switch from {self.mode} to {mode} only "
                                   "at standstill or while disabled (homing)")  # fmt: skip
        # The mode is known as commanded before the engine can act on it: whoever sees the
        # engine end a trajectory for the change (trajectory_stop_reason) sees the new mode.
        previous = self._bus.axis_modes.get(self._index)
        self._bus.axis_modes[self._index] = mode
        try:
            self._bus.engine.axis_set_mode(self._index, mode)
        except BaseException:
            if previous is None:
                self._bus.axis_modes.pop(self._index, None)
            else:
                self._bus.axis_modes[self._index] = previous
            raise
        lo, hi = self.spec.config.position_limits

        def problem(st: dict[str, Any]) -> str | None:
            if "mode_display" in self.spec.variables and st["mode_display"] != mode:
                return f"0x6061 shows {st['mode_display']}, not {mode}"
            if st["state"] in ("fault", "fault_reaction_active"):
                return f"the drive is in {st['state']} (error code 0x{st['error_code']:04X})"
            if st["outside_limits"]:
                return (f"the axis is outside its position limits [{lo:g}, {hi:g}] at "
                        f"{st['position']:.4g}")  # fmt: skip
            return None

        self._wait(lambda st: problem(st) is None, timeout, f"run mode {mode}", problem)

    # ------------------------------------------------------------------------ motion
    def command(
        self,
        position: float | None = None,
        velocity: float | None = None,
        torque: float | None = None,
        *,
        profile_velocity: float | None = None,
        profile_acceleration: float | None = None,
        profile_deceleration: float | None = None,
    ) -> None:
        """One setpoint in SI units, of the kind the mode takes (position for csp/pp, velocity
        for csv/pv, torque for cst). In pp and pv the profile (SI /s, /s²) may come with it:
        written to 0x6081/0x6083/0x6084 before the setpoint (SDO). Refused, with nothing
        written: NaN, beyond the limits, the wrong kind for the mode, a profile outside pp/pv
        or not positive, or the bus not running."""
        given = {k: v for k, v in (("position", position), ("velocity", velocity),
                                   ("torque", torque)) if v is not None}  # fmt: skip
        if len(given) != 1:
            raise AxisCommandError(f"axis {self.name}: give exactly one of position, velocity, "
                                   f"torque (got {', '.join(given) or 'none'})")  # fmt: skip
        ((kind, value),) = given.items()
        self.check_command(kind, value)
        profile = {k: v for k, v in (("profile_velocity", profile_velocity),
                                     ("profile_acceleration", profile_acceleration),
                                     ("profile_deceleration", profile_deceleration))
                   if v is not None}  # fmt: skip
        raws = self._profile_raws(profile)
        self.require_running()
        for key, raw in raws.items():
            index = PROFILE_OBJECTS[key] + self.spec.axis_index * AXIS_STRIDE
            self._bus.sdo_write(self.spec.slave, index, 0, raw, "uint32")
        self._bus.engine.axis_setpoint(self._index, kind, float(value))

    def _profile_raws(self, profile: Mapping[str, float]) -> dict[str, int]:
        """A pp/pv profile in the drive's units, or AxisCommandError saying why not."""
        if profile and self.mode not in ("pp", "pv"):
            raise AxisCommandError(f"axis {self.name}: a profile ({', '.join(profile)}) is for "
                                   f"modes pp and pv (the axis is in {self.mode})")  # fmt: skip
        raws = {}
        for key, v in profile.items():
            if (
                isinstance(v, bool)
                or not isinstance(v, int | float)
                or not math.isfinite(v)
                or (v <= 0)
            ):
                raise AxisCommandError(f"axis {self.name}: {key} {v!r} must be a positive "
                                       "number")  # fmt: skip
            try:
                raws[key] = profile_raw(self.spec.config, key, float(v))
            except ValueError as exc:
                raise AxisCommandError(f"axis {self.name}: {exc}") from None
        return raws

    def check_command(self, kind: str, value: float) -> None:
        """Raise :class:`AxisCommandError` if ``command(**{kind: value})`` would be refused for
        its kind (the mode's) or its value; writes nothing. Lets a caller check the setpoints
        of several axes before commanding any (all or nothing)."""
        want = SETPOINT_KIND[self.mode]
        if kind != want:
            raise AxisCommandError(f"axis {self.name}: a {kind} command for an axis in mode "
                                   f"{self.mode} (it takes {want or 'no setpoint'})")  # fmt: skip
        self._check_value(kind, value)

    def follow(
        self,
        trajectory: Iterable[TrajectoryPoint | tuple[float, ...]],
        start_in: float = 0.0,
    ) -> float:
        """Run a timed trajectory on the engine's clock: points ``(t, position, velocity)``
        (seconds from the start, SI), t strictly increasing; position mode interpolates
        positions (cubic, with the velocities), velocity mode the velocities linearly. Starts
        ``start_in`` seconds from now; from the cycle the engine takes it over, the axis moves
        from the state it is commanded to have to the first point (held when they are equal),
        within its ``max_acceleration`` and velocity limit; points not after that cycle (a first
        point at t = 0 with ``start_in`` 0) are replaced by the commanded state, never steered
        back to (docs/cia402.md, "Hand-overs").
        Returns the start time (engine clock, s). Several axes together: ``bus.follow``."""
        return follow_together(self._bus, {self: trajectory}, start_in)

    def check_trajectory(
        self, trajectory: Iterable[TrajectoryPoint | tuple[float, ...]]
    ) -> list[TrajectoryPoint]:
        """The points :meth:`follow` would run, or :class:`AxisCommandError` saying why it
        would refuse them (mode, times, values, limits); writes nothing."""
        if self.mode not in ("csp", "csv"):
            raise AxisCommandError(f"axis {self.name}: trajectories need mode csp or csv "
                                   f"(the axis is in {self.mode})")  # fmt: skip
        points = [p if isinstance(p, TrajectoryPoint) else TrajectoryPoint(*p) for p in trajectory]
        if not points:
            raise AxisCommandError(f"axis {self.name}: the trajectory has no points")
        for i, p in enumerate(points):
            if not all(math.isfinite(x) for x in (p.t, p.position, p.velocity)) or p.t < 0:
                raise AxisCommandError(f"axis {self.name}: trajectory point {i} {p} is not "
                                       "finite or has t < 0")  # fmt: skip
            if i and p.t <= points[i - 1].t:
                raise AxisCommandError(f"axis {self.name}: trajectory point {i}: t {p.t} is not "
                                       f"after {points[i - 1].t}")  # fmt: skip
            if self.mode == "csp":
                self._check_value("position", p.position, f"trajectory point {i}: ")
            self._check_value("velocity", p.velocity, f"trajectory point {i}: ")
            if i and self.mode == "csp":
                # A segment that needs more than the velocity limit on average cannot be
                # followed (the engine would only clamp it).
                limit = self.spec.config.velocity_limit
                speed = abs(p.position - points[i - 1].position) / (p.t - points[i - 1].t)
                if speed > limit * (1 + 1e-9):
                    raise AxisCommandError(f"axis {self.name}: trajectory points {i - 1}..{i} "
                                           f"need {speed:g} on average, beyond the velocity "
                                           f"limit ±{limit:g}")  # fmt: skip
        return points

    def quiet_stop(self) -> None:
        """Decelerate from the motion the axis is commanded to have to rest at its
        ``deceleration`` and hold (ends a trajectory or a setpoint stream; pp: a set-point where
        that stop ends; cst: zero torque). Several axes in the same cycle: ``bus.quiet_stop``."""
        self.require_running()
        self._bus.engine.axis_stop([self._index])

    def wait_trajectory(self, timeout: float) -> None:
        """Until the trajectory last started on this axis has run to its end (or a later
        command replaced it); feeds the command watchdog while it waits. Raises
        :class:`TrajectoryStopped` with the reason as soon as the trajectory cannot end by
        itself: this axis or another one of it left the state it needs (mode change, disable,
        fault, quick stop, panic, watchdog; the engine has stopped every axis of it)."""
        seq = self._bus.axis_trajectories.get(self._index, 0)

        def done(st: dict[str, Any]) -> bool:
            if st["command_seq"] > seq:
                return True
            if st["command_seq"] == seq and st["trajectory_done"] and not st["trajectory_active"]:
                return True
            why = self.trajectory_stop_reason(st) if seq and st["command_seq"] == seq else None
            if why is not None:
                raise TrajectoryStopped(why)
            return False

        self._wait(done, timeout, "finish its trajectory")

    def trajectory_stop_reason(self, st: Mapping[str, Any] | None = None) -> str | None:
        """Why the trajectory last started on this axis cannot go on (``TrajectoryStopped``'s
        reason), or None while it can (or none was started); ``st``: a status just read."""
        start = self._bus.axis_trajectory_starts.get(self._index)
        if start is None:
            return None
        st = self.status() if st is None else st
        panicked = bool(self._bus.engine.is_panicked)
        own = self.own_stop_reason(st, panicked)
        if own is not None or not self.stopped_with_trajectory(st):
            return own
        # Stopped because another axis of the same trajectory left it: name that one's reason.
        for peer in self._bus.axes():
            peer_start = self._bus.axis_trajectory_starts.get(peer.index)
            if (
                peer.index != self._index
                and peer_start is not None
                and (peer_start.seq == start.seq)
            ):
                why = peer.own_stop_reason(peer.status(), panicked)
                if why is not None:
                    return why
        return stopped_with_trajectory(self.name)

    def stopped_with_trajectory(self, st: Mapping[str, Any]) -> bool:
        """The engine ended the trajectory last started on this axis early (its flag
        ``trajectory_stopped``, for this trajectory: not one before it that the engine has not
        replaced yet)."""
        start = self._bus.axis_trajectory_starts.get(self._index)
        return (
            start is not None
            and bool(st["trajectory_stopped"])
            and int(st["command_seq"]) == start.seq
        )

    def own_stop_reason(self, st: Mapping[str, Any], panicked: bool) -> str | None:
        """This axis's own reason to leave the trajectory last started on it (not "stopped
        with its trajectory", which the engine's flag ``trajectory_stopped`` says when another
        axis of it left it), from a status just read; None: none (or no trajectory)."""
        start = self._bus.axis_trajectory_starts.get(self._index)
        if start is None:
            return None
        return trajectory_stop_reason(self.name, start.mode, self.mode, st, panicked, start.faults)

    # ------------------------------------------------------------------------ extras
    @property
    def extras(self) -> dict[str, float]:
        """The axis's extras (``extras:`` in the configuration) in SI units: inputs as last
        received, outputs as commanded."""
        self.require_running()
        out = {}
        for name, e in self.spec.extras.items():
            raw = self._bus.read(self.spec.slave, e.variable.key)
            out[name] = float(raw) * e.factor + e.offset
        return out

    def set_extras(self, values: Mapping[str, float]) -> None:
        """Command writable extras (outputs: digital outputs, offsets as feed-forward, ...) in
        SI units, all in the same cycle. Refused, with nothing written: an unknown extra, an
        input, NaN, a value its object cannot hold."""
        raws = {}
        for name, value in values.items():
            e = self.spec.extras.get(name)
            if e is None:
                known = ", ".join(self.spec.extras) or "none"
                raise AxisCommandError(f"axis {self.name}: no extra {name!r} (extras: {known})")
            if not e.writable:
                raise AxisCommandError(f"axis {self.name}: extra {name!r} "
                                       f"({e.variable.key}) is an input")  # fmt: skip
            if (
                isinstance(value, bool)
                or not isinstance(value, int | float)
                or not math.isfinite(value)
            ):
                raise AxisCommandError(f"axis {self.name}: extra {name!r}: {value!r} is not a "
                                       "finite number")  # fmt: skip
            raw: float | int = (float(value) - e.offset) / e.factor
            if e.variable.dtype.kind in ("int", "uint", "bool"):
                raw = round(raw)
            try:
                e.variable.encode(raw)
            except ProcessValueError as exc:
                raise AxisCommandError(f"axis {self.name}: extra {name!r}: {exc}") from None
            raws[e.variable.key] = raw
        self.require_running()
        self._bus.write_many(self.spec.slave, raws)

    # ------------------------------------------------------------------------ homing
    def home(self, method: int | None = None, timeout: float = 30.0) -> None:
        """Home the axis (mode hm) at standstill: the method given (written to 0x6098 first;
        refused when the drive does not offer it), else the configured one (``homing:``, set
        in PREOP with its speeds, acceleration and offset). Returns once the drive reports
        homing attained, the axis back in its previous mode, holding where homing left it;
        :class:`AxisError` for a homing error or no end within ``timeout``."""
        self.require_running()
        if "hm" not in self.spec.modes:
            raise AxisCommandError(f"axis {self.name}: the drive does not offer homing (mode hm; "
                                   f"it offers {', '.join(self.spec.modes)})")  # fmt: skip
        if method is not None:
            methods = self.spec.homing_methods or self._read_homing_methods()
            if methods is not None and method not in methods:
                raise AxisCommandError(f"axis {self.name}: the drive does not offer homing "
                                       f"method {method} (0x60E3: "
                                       f"{', '.join(map(str, methods))})")  # fmt: skip
        st = self.status()
        if st["state"] != "operation_enabled":
            raise AxisCommandError(f"axis {self.name}: homing needs the axis enabled (it is in "
                                   f"{st['state']})")  # fmt: skip
        if not st["idle"]:
            raise AxisCommandError(f"axis {self.name}: homing only at standstill")
        if method is not None:
            index = HOMING_OBJECTS["method"] + self.spec.axis_index * AXIS_STRIDE
            self._bus.sdo_write(self.spec.slave, index, 0, method, "int8")
        previous = self.mode
        if previous != "hm":
            self.set_mode("hm", timeout=2.0)
        try:
            runs = int(self.status()["homing_runs"])
            self._bus.engine.axis_home(self._index)
            self._wait(lambda s: int(s["homing_runs"]) > runs, timeout, "finish homing")
            st = self.status()
            if st["homing_error"] or not st["homing_attained"]:
                raise AxisError(f"axis {self.name}: homing error (statusword "
                                f"0x{st['statusword']:04X})")  # fmt: skip
        finally:
            if previous != "hm":
                self.set_mode(previous, timeout=2.0)

    def _read_homing_methods(self) -> tuple[int, ...] | None:
        """0x60E3 (supported homing methods) as the drive answers, or None when it has none."""
        index = SUPPORTED_HOMING_METHODS + self.spec.axis_index * AXIS_STRIDE
        try:
            count = int(self._bus.sdo_read(self.spec.slave, index, 0, "uint8"))  # type: ignore[call-overload]
            return tuple(
                int(self._bus.sdo_read(self.spec.slave, index, k, "int8"))  # type: ignore[call-overload]
                for k in range(1, count + 1)
            )
        except BusError:
            return None

    # ------------------------------------------------------------------------ helpers
    def _check_value(self, kind: str, value: float, what: str = "") -> None:
        c = self.spec.config
        if (
            isinstance(value, bool)
            or not isinstance(value, int | float)
            or not math.isfinite(value)
        ):
            raise AxisCommandError(f"axis {self.name}: {what}{kind} {value!r} is not a finite "
                                   "number")  # fmt: skip
        if kind == "position":
            lo, hi = c.position_limits
            if not lo <= value <= hi:
                raise AxisCommandError(f"axis {self.name}: {what}position {value:g} is outside "
                                       f"the limits [{lo:g}, {hi:g}]")  # fmt: skip
        else:
            limit = c.velocity_limit if kind == "velocity" else c.torque_limit
            if abs(value) > limit:
                raise AxisCommandError(f"axis {self.name}: {what}{kind} {value:g} is beyond the "
                                       f"limit ±{limit:g}")  # fmt: skip

    def require_running(self) -> None:
        if not self._bus.running:
            raise AxisCommandError(f"axis {self.name}: the bus is not in OP (call start())")

    def require_enabled(self, what: str) -> None:
        """Refuse ``what`` while the drive is not in Operation Enabled: the engine would take
        it and never run it (the targets follow the actual state until the drive runs), so
        the caller gets the reason and what to do instead of an 'accepted' that moves
        nothing (issue 19)."""
        st = self.status()
        state = str(st["state"])
        if state == "operation_enabled":
            return
        if state in ("fault", "fault_reaction_active"):
            code = int(st["error_code"]) or int(st["last_fault_code"])
            raise AxisCommandError(
                f"axis {self.name} is in {state} (error 0x{code:04X}: {emergency_text(code)}): "
                f"{what} is refused; reset_fault, then enable the axis"
            )
        raise AxisCommandError(
            f"axis {self.name} is {state}, not operation_enabled: {what} is refused; "
            "enable the axis first"
        )

    def _wait(
        self,
        done: Any,
        timeout: float,
        what: str,
        problem: Callable[[dict[str, Any]], str | None] | None = None,
    ) -> None:
        """Poll the status until ``done``; the caller is alive and waiting for this axis, so
        the wait feeds the command watchdog (``bus.watchdog_ms``)."""
        deadline = time.monotonic() + timeout
        while True:
            st = self.status()
            if done(st):
                return
            if time.monotonic() > deadline:
                why = problem(st) if problem is not None else None
                raise AxisError(
                    f"axis {self.name}: did not {what} within {timeout:g} s: "
                    + (f"{why}; " if why else "")
                    + f"in {st['state']} (statusword 0x{st['statusword']:04X}, error code "
                    f"0x{st['error_code']:04X})"
                )
            self._bus.feed_watchdog()
            time.sleep(POLL_S)


# -- the bus's axes, by name (``Bus.follow``, ``quiet_stop``, ``wait_trajectories``, ``axis``) --
def find(bus: Bus, name: str) -> Axis:
    """A CiA 402 axis of ``bus`` by joint name."""
    for a in bus.axes():
        if a.name == name:
            return a
    names = ", ".join(a.name for a in bus.axes()) or "none"
    raise AxisCommandError(f"no axis {name!r} on this bus (axes: {names})")


def chosen(bus: Bus, names: Iterable[str] | None) -> list[Axis]:
    """The axes named (every axis of the bus by default)."""
    return [find(bus, n) for n in names] if names is not None else bus.axes()


def follow_named(
    bus: Bus,
    tracks: Mapping[str, Iterable[TrajectoryPoint | tuple[float, ...]]],
    start_in: float,
) -> float:
    """``Bus.follow``: one trajectory for several axes by joint name, all started in the same
    cycle; every axis's points checked first (all or nothing)."""
    by_name = {a.name: a for a in bus.axes()}
    unknown = [n for n in tracks if n not in by_name]
    if unknown:
        names = ", ".join(by_name) or "none"
        raise AxisCommandError(f"no axis {unknown[0]!r} on this bus (axes: {names})")
    return follow_together(bus, {by_name[n]: points for n, points in tracks.items()}, start_in)


def quiet_stop_named(bus: Bus, names: Iterable[str] | None) -> None:
    """``Bus.quiet_stop``: a quiet stop on the axes named, all in the same cycle."""
    axes = chosen(bus, names)
    if axes:
        if not bus.running:
            raise AxisCommandError("the bus is not in OP (call start())")
        bus.engine.axis_stop([a.index for a in axes])


def wait_named(bus: Bus, names: Iterable[str] | None, timeout: float) -> None:
    """``Bus.wait_trajectories``: until the last trajectory of each axis named has run out."""
    deadline = time.monotonic() + timeout
    for a in chosen(bus, names):
        a.wait_trajectory(max(deadline - time.monotonic(), 0.0))


def stop_all(engine: Any, count: int, wait_s: float) -> None:
    """Every axis to its on_stop command, and a moment (``wait_s`` at most) for the drives to
    leave Operation Enabled (bounded: the stop goes on the wire whatever the drives answer)."""
    for i in range(count):
        engine.axis_enable(i, False)
    deadline = time.monotonic() + wait_s
    while count and time.monotonic() < deadline:
        states = [engine.axis_status(i)["state"] for i in range(count)]
        if "operation_enabled" not in states:
            break
        time.sleep(0.005)


def axis_blocker(
    st: Mapping[str, Any],
    mode: str = "",
    panic: bool = False,
    check_mode: bool = True,
    cause: str = "",
) -> str:
    """Why an axis with this ``Axis.status()`` cannot follow a setpoint now ("" when it can):
    one sentence for the diagnostics, the console and the answers to commands that were not
    executed. ``panic``: the bus is in panic (the node knows it; the axis only sees a halt);
    ``check_mode``: a mode not reached yet counts (not while a mode change is under way);
    ``cause``: what stopped the axis when the node saw it (``"the command watchdog"``)."""
    state = str(st.get("state", ""))
    code = int(st.get("error_code", 0) or 0) or int(st.get("last_fault_code", 0) or 0)
    if state in ("fault", "fault_reaction_active"):
        text = f"0x{code & 0xFFFF:04X} {emergency_text(code)}" if code else "no code"
        return f"in fault ({text}): reset_fault, then enable"
    if panic:
        return "the bus is in panic: clear_panic, then enable"
    if st.get("restart_blocked"):
        last = int(st.get("last_fault_code", 0) or 0)
        fault = f"; last fault 0x{last & 0xFFFF:04X} {emergency_text(last)}" if last else ""
        by = cause or "the watchdog, a panic, a lease lapse or a fault"
        return (
            f"restart blocked: stopped by {by} ({state}) and waiting for an explicit enable{fault}"
        )
    # A halt alone (the command watchdog's stop) is not reported: the next command ends it.
    if state != "operation_enabled":
        if cause:
            return f"disabled by {cause} ({state}): enable it again"
        return f"not enabled ({state}): enable it first"
    if check_mode and not st.get("mode_reached", True):
        shown = st.get("mode_display") or st.get("mode_display_code")
        return f"mode {mode or '?'} not reached (the drive shows {shown})"
    return ""
