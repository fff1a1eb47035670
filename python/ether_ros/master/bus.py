"""The master's public face: open a bus from its configuration, bring it to OP, exchange process
data by variable name, and supervise it.

    bus = Bus.open("config/laelaps.yaml", interface="eth1")
    bus.start()                                   # INIT → PREOP → SAFEOP → OP, cyclic running
    bus.write("front_left_leg", "State_Machine", 1)
    bus.read("front_left_leg", "hip_angle")
    bus.stop(); bus.close()

Threads: the engine's real-time thread runs the cyclic frame; ``Bus`` methods run in the
caller's thread; a supervisor thread (plain Python) watches the slaves during OP. Everything
that talks to the wire acyclically holds ``_acyclic`` so the supervisor and API calls never
interleave mailbox exchanges with each other.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import Any

from ether_ros._native import Plan as EnginePlan
from ether_ros._native.protocol import reg
from ether_ros.claim import InterfaceClaim
from ether_ros.config import types as dt
from ether_ros.config.bus import DEFAULT_GROUP
from ether_ros.config.cia402 import AxisSpec
from ether_ros.config.esi import EsiDevice
from ether_ros.config.process import (
    ProcessLayout,
    ProcessValueError,
    ProcessVariable,
    Value,
    write_bits,
)
from ether_ros.errors import BusError, ConfigError, EtherRosError, LinkError
from ether_ros.master import axis as axis_mod
from ether_ros.master import bringup, workspace
from ether_ros.master.al import AlState, AlStateMachine, AlStatus, al_code_text
from ether_ros.master.datagrams import DatagramService
from ether_ros.master.dc import EPOCH_2000_S, DcSlave, DistributedClocks
from ether_ros.master.events import BusEvent
from ether_ros.master.groups import GroupStats, group_stats
from ether_ros.master.link import open_engine
from ether_ros.master.pdo import select_pdos
from ether_ros.master.plan import (
    DcPlan,
    ImageLayout,
    ImageSlave,
    RtPlan,
    build_plan,
    layout_image,
)
from ether_ros.master.samples import Samples, decode_samples
from ether_ros.master.scan import (
    Expected,
    FoundSlave,
    bus_tree,
    match_configuration,
    match_topology,
    scan,
)
from ether_ros.master.service import serve_bus
from ether_ros.master.shared_frames import run_in_parallel
from ether_ros.master.slave import Slave
from ether_ros.master.supervisor import Supervisor
from ether_ros.topology import Link, line

log = logging.getLogger(__name__)

# How long stop() gives the drives to leave Operation Enabled after their on_stop command.
AXIS_STOP_WAIT_S = 0.5
# A late wake-up of the cyclic thread on a busy host leaves a frame without its whole reply for
# a few cycles: a read waits this long for a fresh reply before it calls the inputs stale (a
# cable pulled or a slave cut off stays stale and is reported then).
STALE_GRACE_S = 0.05

__all__ = ["Bus", "BusEvent", "StaleInputs"]


class StaleInputs(BusError):
    """Inputs that are not fresh: the bus is not running, or no reply to the frame carrying
    the slave's inputs came back whole (every working counter as expected) within two of its
    periods — a cable pulled, the slave cut off or gone. Names the slave and since when."""


def _now_monotonic_ns() -> int:
    return time.clock_gettime_ns(time.CLOCK_MONOTONIC)


@dataclass(frozen=True)
class SlaveState:
    name: str
    position: int
    station: int
    state: str
    error: bool
    code: int
    text: str
    # Why the supervisor considers the slave lost ('' when it is fine).
    problem: str = ""

    def as_dict(self) -> dict[str, Any]:
        return dict(self.__dict__)


class Bus:
    """An EtherCAT bus driven by the engine; see the module doc."""

    def __init__(self, config: Any, engine: Any, drift_frames: int | None = None) -> None:
        self.config = config
        self.engine = engine
        self.dg = DatagramService(engine)
        self.al = AlStateMachine(self.dg)
        self.slaves: list[Slave] = []
        # Where each slave hangs (by position), as found on the wire.
        self.tree: list[Link] = []
        self.layout: ImageLayout | None = None
        self.plan: EnginePlan | None = None
        self.cycle_ns = int(config.bus.cycle_us * 1000)
        # DC system time = CLOCK_MONOTONIC + this: nanoseconds since 2000-01-01 (wall clock at
        # open time), so DC timestamps read like dates.
        self.time_offset_ns = time.time_ns() - _now_monotonic_ns() - EPOCH_2000_S * 1_000_000_000
        self.dc = DistributedClocks(
            self.dg, self.master_time, drift_frames=3000 if drift_frames is None else drift_frames
        )
        self.dc_reference: Slave | None = None
        self._acyclic = threading.RLock()
        # Serialises output writes so the mirror below changes in the engine's order.
        self._output_lock = threading.Lock()
        # Python's copy of the output image: what the plan starts from, and what reads of outputs
        # return while not running. While running the engine's buffer is the truth (other
        # writers, e.g. a native command thread, change it too).
        self._outputs = bytearray()
        self._safe = b""
        self._running = False
        self._closed = False
        self._listeners: list[Callable[[BusEvent], None]] = []
        self.supervisor: Supervisor | None = None
        # The interface claimed for this master (None on an in-process link): the inspection
        # tools of other processes reach the bus through it (master/service.py).
        self.claim: InterfaceClaim | None = None
        # Why a write from another process (an SDO download through the claim) is refused
        # now, or None: the ROS node sets it to its control lease's rule.
        self.remote_write_refusal: Callable[[], str | None] = lambda: None
        # Image byte → axis name of the output bytes the engine's axis stage owns (lazily).
        self._axis_owned: dict[int, str] | None = None
        # Per engine axis index, for this cyclic run: the mode last commanded and the number of
        # the last trajectory started, and how it started (shared by every Axis object of the
        # axis).
        self.axis_modes: dict[int, str] = {}
        self.axis_trajectories: dict[int, int] = {}
        self.axis_trajectory_starts: dict[int, axis_mod.TrajectoryStart] = {}

    # ---------------------------------------------------------------------------- opening
    @classmethod
    def open(
        cls,
        config: Any,
        interface: str | None = None,
        link: Any = None,
        drift_frames: int | None = None,
    ) -> Bus:
        """Open the link (``interface``, or ``link``: an in-process ``SimNetwork``), scan the
        bus and check it against the configuration. The slaves stay in INIT until ``start``."""
        cfg = _load_config(config)
        from ether_ros import _native

        claim = None
        if link is not None:
            engine = _native.Engine.open_sim(link)
        else:
            ifname = interface or getattr(cfg.bus, "interface", None)
            if not ifname:
                raise LinkError("no network interface: give --interface or bus.interface")
            # One master per interface: a second one would take the running one's slaves
            # down to INIT under it (docs/master.md, "One master per interface").
            claim = InterfaceClaim.take(ifname, "master")
            try:
                engine = open_engine(
                    ifname, cfg.bus.link, cfg.bus.busy_poll_us, qdisc_bypass=not cfg.bus.capture
                )
            except BaseException:
                claim.release()
                raise
        bus = cls(cfg, engine, drift_frames=drift_frames)
        try:
            bus._discover()
        except BaseException:
            engine.close()
            if claim is not None:
                claim.release()
            raise
        if claim is not None:
            bus.claim = claim
            serve_bus(claim, bus)
        return bus

    def master_time(self) -> int:
        """The master's DC system time now (ns since 2000)."""
        now = getattr(self.engine, "now_ns", None)
        return (now() if now is not None else _now_monotonic_ns()) + self.time_offset_ns

    def _check_found(self, found: list[FoundSlave]) -> list[int]:
        """The tree of ``found`` (kept in ``self.tree``), checked against the configured one
        when the configuration describes it, then the identities; returns each configured
        slave's position."""
        declared = getattr(self.config, "declares_topology", False)
        try:
            self.tree = bus_tree(found)
        except BusError as exc:
            if declared:
                raise
            # A configuration of a line does not depend on the ports: carry on as one.
            log.warning("%s; taking the bus for a line", exc)
            self.tree = line(len(found))
        if declared:
            names = [s.name for s in self.config.by_position()]
            match_topology(self.tree, self.config.tree(), names)
        expected = [_expected(s, i) for i, s in enumerate(self.config.slaves)]
        return match_configuration(found, expected)

    def _discover(self) -> None:
        with self._acyclic:
            found = scan(self.dg)
            positions = self._check_found(found)
            slaves = [
                self._make_slave(cfg, found[pos])
                for cfg, pos in zip(self.config.slaves, positions, strict=True)
            ]
            slaves.sort(key=lambda s: s.position)
            self.slaves = slaves
            self._setup_dc_roles()
            self.layout = layout_image(
                [self._image_slave(s) for s in slaves],
                groups=self._group_cycles(),
                dc=self.dc_reference is not None,
            )
            for s, area in zip(slaves, self.layout.slaves, strict=True):
                s.area = area
            self._safe = self._safe_image()
            self._outputs = bytearray(self._safe)

    def _group_cycles(self) -> list[tuple[str, int]]:
        """(group, base cycles per group cycle): the default group first."""
        cycles = getattr(self.config, "group_cycles", None)
        return cycles() if cycles is not None else [(DEFAULT_GROUP, 1)]

    def _image_slave(self, s: Slave) -> ImageSlave:
        """What the image layout needs of ``s``: sizes, group, and whether it takes LRW (not
        when its ESC says LRW is unsupported, nor when the config asks for LRD + LWR)."""
        group = self._group(s.name)
        lrw = (
            s.found.lrw_supported
            and bool(getattr(s.config, "lrw", True))
            and (group is None or group.lrw)
        )
        return ImageSlave(
            s.position,
            s.station,
            s.name,
            s.layout.output_bytes if s.layout else 0,
            s.layout.input_bytes if s.layout else 0,
            group.name if group is not None else DEFAULT_GROUP,
            lrw,
        )

    def _make_slave(self, cfg: Any, found: FoundSlave) -> Slave:
        who = f"slave {found.position} ({cfg.name})"
        device = _device_for(self.config, cfg)
        assign = getattr(cfg, "pdo_assign", None)
        rx = list(assign.rx) if assign is not None and assign.rx is not None else None
        tx = list(assign.tx) if assign is not None and assign.tx is not None else None
        selection = select_pdos(who, device, rx, tx)
        layout = None
        if device is not None:
            try:
                layout = ProcessLayout.for_device(device, selection.rx, selection.tx)
            except ConfigError as exc:
                raise BusError(f"{who}: {exc}") from None
        return Slave(
            name=cfg.name,
            position=found.position,
            station=found.station,
            found=found,
            config=cfg,
            device=device,
            selection=selection,
            layout=layout,
        )

    def _setup_dc_roles(self) -> None:
        dc_cfg = getattr(self.config.bus, "dc", None)
        self.dc_reference = None
        if dc_cfg is None or not dc_cfg.enabled:
            return
        capable = [s for s in self.slaves if s.found.dc_supported]
        if not capable:
            raise BusError("distributed clocks are enabled but no slave supports them")
        ref_pos = getattr(dc_cfg, "reference", None)
        reference = capable[0]
        if ref_pos is not None and ref_pos != reference.position:
            raise BusError(
                f"DC reference clock must be the first DC-capable slave "
                f"(slave {reference.position}, {reference.name}); configured: {ref_pos}"
            )
        self.dc_reference = reference
        for s in capable:
            aa = s.device.assign_activate if s.device is not None else 0
            if s.device is None and s.found.header.dc:
                aa = next((m.assign_activate for m in s.found.header.dc if m.assign_activate), 0)
            s.dc = DcSlave(
                s.position, s.station, s.name, assign_activate=aa,
                sync0_cycle_ns=self._group_every(s.name) * self.cycle_ns,
            )  # fmt: skip

    def _group(self, slave: str) -> Any:
        """The config's group of ``slave`` (None: the default group)."""
        group_of = getattr(self.config, "group_of", None)
        return group_of(slave) if group_of is not None else None

    def _group_every(self, slave: str) -> int:
        """Base cycles per cycle of ``slave``'s group."""
        group = self._group(slave)
        return dict(self._group_cycles())[group.name] if group is not None else 1

    def _safe_image(self) -> bytes:
        assert self.layout is not None
        image = bytearray(self.layout.output_bytes)
        for s in self.slaves:
            if s.layout is None or s.area is None or not s.area.output_bytes:
                continue
            values = dict(getattr(s.config, "safe_outputs", None) or {})
            try:
                area = s.layout.pack_outputs(values)
            except ProcessValueError as exc:
                raise ConfigError(f"slaves.{s.name}.safe_outputs: {exc}") from None
            image[s.area.output_offset : s.area.output_offset + s.area.output_bytes] = area
        return bytes(image)

    # ---------------------------------------------------------------------------- start/stop
    @property
    def running(self) -> bool:
        return self._running

    def start(self) -> None:
        """INIT → PREOP → SAFEOP → OP with checks at each step, then supervise."""
        if self._closed:
            raise BusError("the bus is closed")
        if self._running:
            return
        self.axis_modes.clear()
        self.axis_trajectories.clear()
        self.axis_trajectory_starts.clear()
        with self._acyclic:
            self._reset_and_verify()
            refs = [s.ref for s in self.slaves]
            self.al.transition(refs, AlState.INIT)
            run_in_parallel(self.dg, self.slaves, bringup.setup_mailbox)
            self.al.transition(refs, AlState.PREOP)
            bringup.configure_all_preop(self.dg, self.slaves)
            dc_slaves = [s.dc for s in self.slaves if s.dc is not None]
            sync0_start = 0
            if self.dc_reference is not None and self.dc_reference.dc is not None:
                ref = self.dc_reference.dc
                self.dc.measure(dc_slaves, self.tree)
                self.dc.compensate_drift(ref)
                sync0_start = self.dc.activate_sync0(
                    dc_slaves, self.cycle_ns, self._sync0_shift_ns, ref
                )
            self.al.transition(refs, AlState.SAFEOP)
            bringup.configure_all_safeop(self.dg, self.slaves)
            # The cyclic frame starts with the safe outputs; writes before start are dropped.
            self._outputs = bytearray(self._safe)
            self.plan = self._build_plan()
            self.engine.start_cyclic(self.plan)
            self._running = True
            try:
                # Slaves check for valid outputs (and running SYNC0) before they accept OP.
                time.sleep(max(5 * self.cycle_ns / 1e9, 0.01))
                while sync0_start and self.master_time() < sync0_start + 2 * self.cycle_ns:
                    time.sleep(0.005)
                self.al.transition(refs, AlState.OP)
            except BaseException:
                self._shutdown_cyclic()
                raise
        self.supervisor = Supervisor(self)
        self.supervisor.start()

    @property
    def _dc_mode(self) -> str:
        if self.dc_reference is None:
            return "off"
        return str(getattr(self.config.bus.dc, "mode", "ref_follows_master"))

    @property
    def _sync0_shift_ns(self) -> int:
        dc_cfg = getattr(self.config.bus, "dc", None)
        return round(float(getattr(dc_cfg, "sync0_shift_us", 0) or 0) * 1000)

    def _reset_and_verify(self) -> None:
        """Scan again (slaves may have been power-cycled since ``open``) and check identity."""
        found = scan(self.dg)
        positions = self._check_found(found)
        by_name = {s.name: s for s in self.slaves}
        for cfg, pos in zip(self.config.slaves, positions, strict=True):
            s = by_name[cfg.name]
            s.found = found[pos]
            s.lost = False

    def _build_plan(self) -> EnginePlan:
        assert self.layout is not None
        bus_cfg = self.config.bus
        rt = getattr(bus_cfg, "realtime", None)
        rt_plan = RtPlan()
        if rt is not None:
            rt_plan = RtPlan(
                policy=str(rt.policy),
                priority=int(rt.priority),
                cpu=rt.cpu,
                runtime_ns=int(getattr(rt, "deadline_runtime_us", 100) * 1000),
                lock_memory=bool(rt.lock_memory),
            )
        dc = DcPlan()
        if self.dc_reference is not None:
            dc = DcPlan(
                mode=self._dc_mode,
                reference_station=self.dc_reference.station,
                time_offset_ns=self.time_offset_ns,
                sync0_shift_ns=self._sync0_shift_ns,
            )
        watchdog_ms = float(getattr(bus_cfg, "watchdog_ms", 0) or 0)
        return build_plan(
            self.layout,
            cycle_ns=self.cycle_ns,
            order=str(getattr(bus_cfg, "cycle_order", "send_at_wake")),
            safe_outputs=self._safe,
            initial_outputs=bytes(self._outputs),
            dc=dc,
            rt=rt_plan,
            watchdog_ns=int(watchdog_ms * 1_000_000),
            axes=axis_mod.plan_entries(self._axis_specs(), self.layout),
            group_watchdog_ns={
                g.name: int(g.watchdog_ms) * 1_000_000
                for g in getattr(self.config, "groups", None) or []
                if g.watchdog_ms
            },
        )

    # ---------------------------------------------------------------------------- axes
    def _axis_specs(self) -> list[AxisSpec]:
        specs = getattr(self.config, "axis_specs", None)
        return list(specs()) if callable(specs) else []

    def axes(self) -> list[axis_mod.Axis]:
        """Every CiA 402 axis of the bus (docs/cia402.md), in bus order."""
        return [axis_mod.Axis(self, i, spec) for i, spec in enumerate(self._axis_specs())]

    def follow(
        self,
        tracks: Mapping[str, Iterable[axis_mod.TrajectoryPoint | tuple[float, ...]]],
        start_in: float = 0.0,
    ) -> float:
        """One trajectory for several axes (by joint name), handed to the engine at once: all
        of them start it in the same cycle (docs/cia402.md, "Trajectories"). Every axis's
        points are checked first (all or nothing). Returns the start time (engine clock, s)."""
        by_name = {a.name: a for a in self.axes()}
        unknown = [n for n in tracks if n not in by_name]
        if unknown:
            names = ", ".join(by_name) or "none"
            raise axis_mod.AxisCommandError(f"no axis {unknown[0]!r} on this bus (axes: {names})")
        return axis_mod.follow_together(
            self, {by_name[n]: points for n, points in tracks.items()}, start_in
        )

    def quiet_stop(self, names: Iterable[str] | None = None) -> None:
        """A quiet stop (``Axis.quiet_stop``) on the axes named (every axis by default), all in
        the same cycle."""
        chosen = [self.axis(n) for n in names] if names is not None else self.axes()
        if chosen:
            if not self.running:
                raise axis_mod.AxisCommandError("the bus is not in OP (call start())")
            self.engine.axis_stop([a.index for a in chosen])

    def wait_trajectories(self, names: Iterable[str] | None = None, timeout: float = 10.0) -> None:
        """Until the trajectory last started on each axis named (every axis by default) has run
        to its end; feeds the command watchdog while it waits. Raises ``TrajectoryStopped``
        naming the axis and why when one of them left the trajectory early (``Axis.
        wait_trajectory``)."""
        chosen = [self.axis(n) for n in names] if names is not None else self.axes()
        deadline = time.monotonic() + timeout
        for a in chosen:
            a.wait_trajectory(max(deadline - time.monotonic(), 0.0))

    def axis(self, name: str) -> axis_mod.Axis:
        """A CiA 402 axis by joint name."""
        for a in self.axes():
            if a.name == name:
                return a
        names = ", ".join(a.name for a in self.axes()) or "none"
        raise axis_mod.AxisCommandError(f"no axis {name!r} on this bus (axes: {names})")

    def _stop_axes(self) -> None:
        """Every axis to its on_stop command, and a moment for the drives to leave Operation
        Enabled (bounded: the stop goes on the wire whatever the drives answer)."""
        specs = self._axis_specs()
        for i in range(len(specs)):
            self.engine.axis_enable(i, False)
        deadline = time.monotonic() + AXIS_STOP_WAIT_S
        while specs and time.monotonic() < deadline:
            states = [self.engine.axis_status(i)["state"] for i in range(len(specs))]
            if "operation_enabled" not in states:
                break
            time.sleep(0.005)

    def stop(self) -> None:
        """Safe outputs on the wire, slaves to SAFEOP then INIT, cyclic exchange stopped."""
        if not self._running:
            return
        if self.supervisor is not None:
            self.supervisor.stop()
            self.supervisor = None
        with self._acyclic:
            self._stop_axes()
            self._outputs = bytearray(self._safe)
            if self._safe:
                self.engine.write_outputs(0, bytes(self._safe))
            time.sleep(max(3 * self.cycle_ns / 1e9, 0.005))
            refs = [s.ref for s in self.slaves]
            try:
                self.al.transition(refs, AlState.SAFEOP)
            except EtherRosError as exc:
                log.warning("stop: not every slave went to SAFEOP: %s", exc)
            self._shutdown_cyclic()
            try:
                dc_slaves = [s.dc for s in self.slaves if s.dc is not None]
                self.dc.deactivate(dc_slaves)
                self.al.transition(refs, AlState.INIT)
            except EtherRosError as exc:
                log.warning("stop: not every slave went to INIT: %s", exc)

    def _shutdown_cyclic(self) -> None:
        try:
            self.engine.stop_cyclic()
        finally:
            self._running = False

    def close(self) -> None:
        if self._closed:
            return
        try:
            self.stop()
        finally:
            self._closed = True
            self.engine.close()
            if self.claim is not None:
                self.claim.release()

    def __enter__(self) -> Bus:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()

    # ---------------------------------------------------------------------------- slaves
    def slave(self, which: str | int) -> Slave:
        """A slave by configured name or bus position."""
        for s in self.slaves:
            if s.name == which or (isinstance(which, int) and s.position == which):
                return s
        names = ", ".join(s.name for s in self.slaves)
        raise BusError(f"no slave {which!r} on this bus (slaves: {names})")

    def _variable(self, slave: Slave, name: str, direction: str | None = None) -> ProcessVariable:
        if slave.layout is None:
            raise BusError(f"{slave}: has no process data")
        try:
            return slave.layout.variable(name, direction)
        except ProcessValueError as exc:
            raise ProcessValueError(f"{slave}: {exc}") from None

    # ---------------------------------------------------------------------------- process data
    def write(self, slave: str | int, variable: str, value: object) -> None:
        """Set one output variable. Unknown variables, inputs, wrong types and out-of-range
        values are refused with :class:`ProcessValueError` before anything reaches the wire."""
        self.write_many(slave, {variable: value})

    def write_many(self, slave: str | int, values: Mapping[str, object]) -> None:
        """Set several outputs of one slave at once (they reach the wire in the same cycle).

        Only the bits of these variables change: the engine merges them into its output buffer
        (``write_output_fields``), so a write never undoes another writer's variables."""
        self.write_slaves({slave: values})

    def write_slaves(self, values: Mapping[str | int, Mapping[str, object]]) -> None:
        """Set outputs of several slaves (slave -> {variable: value}) at once: every value is
        checked — variable, type, range, and the device's own rule (a Laelaps II leg's
        trajectory must stay in its workspace, :mod:`ether_ros.master.workspace`) — before any
        is written, and all reach the wire in the same cycle. A bad value changes nothing."""
        fields: list[tuple[int, int, int]] = []
        for slave, slave_values in values.items():
            fields.extend(self._checked_fields(self.slave(slave), slave_values))
        self._write_fields(fields)

    def write_all(self, variable: str, value: object) -> int:
        """Set ``variable`` on every slave that has it as an output; returns how many. All of
        them reach the wire in the same cycle, and a bad value changes nothing."""
        targets = [
            s
            for s in self.slaves
            if s.layout is not None
            and s.layout.has(variable)
            and s.layout.variable(variable, "output").direction == "output"
        ]
        if not targets:
            raise ProcessValueError(f"no slave has an output variable {variable!r}")
        self.write_slaves({s.name: {variable: value} for s in targets})
        return len(targets)

    def _checked_fields(self, s: Slave, values: Mapping[str, object]) -> list[tuple[int, int, int]]:
        """The output fields of ``values`` for slave ``s``, every one checked."""
        area = s.area
        if s.layout is None or area is None or not area.output_bytes:
            raise BusError(f"{s}: has no outputs")
        variables: list[ProcessVariable] = []
        for name in values:
            var = self._variable(s, name, "output")
            if var.direction != "output":
                raise ProcessValueError(f"{s}: variable {name!r} is an input, not an output")
            self._refuse_axis_owned(s, var)
            variables.append(var)
        fields: list[tuple[int, int, int]] = []
        for var, value in zip(variables, values.values(), strict=True):
            try:
                fields.append(_output_field(s, var, var.encode(value)))
            except ProcessValueError as exc:
                raise ProcessValueError(f"{s}: {exc}") from None
        assigned = dict(zip((v.name for v in variables), values.values(), strict=True))
        self._check_device_rule(s, assigned)
        return fields

    def _check_device_rule(self, s: Slave, assigned: Mapping[str, object]) -> None:
        """What the device itself would refuse or disregard, refused here with the reason."""
        if s.device is None or s.layout is None:
            return
        outputs = [(v.name, v.index, v.subindex) for v in s.layout.outputs]
        if not workspace.is_laelaps_leg(s.device.type_name, outputs):
            return
        current = {
            k: float(v) for k, v in self.outputs(s.name).items() if isinstance(v, int | float)
        }
        numbers = {k: float(v) for k, v in assigned.items() if isinstance(v, int | float)}
        problem = workspace.leg_write_problem(s.device.type_name, outputs, current, numbers)
        if problem is not None:
            raise ProcessValueError(f"{s}: {problem}")

    def _refuse_axis_owned(self, s: Slave, var: ProcessVariable) -> None:
        """The engine's axis stage writes its drives' controlwords, modes and targets every
        cycle: a variable write there would be overwritten, so it is refused."""
        if self.layout is None or s.area is None:
            return
        if self._axis_owned is None:
            self._axis_owned = axis_mod.output_bits(self._axis_specs(), self.layout)
        owned = self._axis_owned
        byte = s.area.output_offset + var.bit_offset // 8
        if byte in owned:
            raise ProcessValueError(f"{s}: variable {var.name!r} belongs to axis {owned[byte]}; "
                                    f"command it with bus.axis({owned[byte]!r})")  # fmt: skip

    def _write_fields(self, fields: list[tuple[int, int, int]]) -> None:
        """Write validated output fields (image bit offset, bit length, raw) to the engine when
        running, and to the mirror."""
        with self._output_lock:
            if self._running:
                self.engine.write_output_fields(fields)
            for bit_offset, bit_length, raw in fields:
                write_bits(self._outputs, bit_offset, bit_length, raw)

    def _output_area(self, s: Slave) -> bytes:
        """The slave's outputs as commanded: the engine's buffer while running (other writers
        may have changed it), else the mirror."""
        assert s.area is not None
        begin, end = s.area.output_offset, s.area.output_offset + s.area.output_bytes
        if self._running:
            return bytes(self.engine.outputs())[begin:end]
        return bytes(self._outputs[begin:end])

    def _input_area(self, s: Slave) -> bytes:
        assert self.layout is not None
        area = s.area
        if area is None:
            return b""
        image = bytes(self.engine.read_inputs()) if self._running else b""
        if len(image) == self.layout.image_len:
            return image[area.input_offset : area.input_offset + area.input_bytes]
        if len(image) == self.layout.input_bytes:
            offset = area.input_offset - self.layout.output_bytes
            return image[offset : offset + area.input_bytes]
        return bytes(area.input_bytes)

    def read(self, slave: str | int, variable: str, stale_ok: bool = False) -> Value:
        """The latest value of an input (as received) or an output (as commanded). An input
        that is not fresh, and not fresh again within ``STALE_GRACE_S``, raises
        :class:`StaleInputs` (``stale_ok``: return the last value received anyway)."""
        s = self.slave(slave)
        var = self._variable(s, variable)
        assert s.layout is not None and s.area is not None
        if var.direction == "output":
            return s.layout.read(self._output_area(s), var)
        if not stale_ok:
            self._check_fresh(s)
        return s.layout.read(self._input_area(s), var)

    def inputs(self, slave: str | int, stale_ok: bool = False) -> dict[str, Value]:
        """Every input of ``slave``; :class:`StaleInputs` when they are not fresh (unless
        ``stale_ok``)."""
        s = self.slave(slave)
        if s.layout is None:
            return {}
        if not stale_ok:
            self._check_fresh(s)
        return s.layout.unpack(self._input_area(s), "input")

    def input_frames(self, slave: str | int) -> tuple[int, ...]:
        """The cyclic frames that carry ``slave``'s process data."""
        s = self.slave(slave)
        if self.layout is None or s.area is None:
            return ()
        return self.layout.frames_of(s.name)

    def inputs_fresh(self, slave: str | int) -> bool:
        """Whether ``slave``'s inputs are fresh now: the bus runs and every frame carrying them
        came back whole within two of its periods (the engine's stale mask)."""
        frames = self.input_frames(slave)
        if not self._running:
            return False
        if not frames:
            return True  # no process data: nothing to be stale
        mask = int(self.engine.stale_mask())
        return not any(mask >> k & 1 for k in frames)

    def input_age(self, slave: str | int) -> float:
        """Seconds since the oldest frame carrying ``slave``'s inputs last came back whole
        (inf: never, or the bus is not running)."""
        frames = self.input_frames(slave)
        if not self._running or not frames:
            return float("inf")
        stats = self.engine.stats().get("frames") or []
        now = _now_monotonic_ns()
        ages = []
        for k in frames:
            f = stats[k] if k < len(stats) else {}
            good = int(f.get("last_good_ns", 0))
            ages.append((now - good) / 1e9 if f.get("last_good_cycle") and good else float("inf"))
        return max(ages)

    def _check_fresh(self, s: Slave) -> None:
        if not self._running:
            raise StaleInputs(f"slave '{s.name}': no inputs, the bus is not running")
        deadline = time.monotonic() + STALE_GRACE_S
        while not self.inputs_fresh(s.name):
            if time.monotonic() < deadline:
                time.sleep(0.001)
                continue
            age = self.input_age(s.name)
            since = "never came back whole" if age == float("inf") else f"{age * 1000:.0f} ms"
            raise StaleInputs(
                f"slave '{s.name}': inputs are stale (its frame's last whole reply: {since}); "
                "the bus or the slave is down"
            )

    def outputs(self, slave: str | int) -> dict[str, Value]:
        s = self.slave(slave)
        if s.layout is None or s.area is None:
            return {}
        return s.layout.unpack(self._output_area(s), "output")

    def samples(self, max_samples: int = 65536) -> Samples:
        """Drain the engine's per-cycle sample ring: ``records`` (the structured array of
        ``master/samples.py``: cycle, wake-up latency, round trip, WKC, flags, ...) and
        ``images`` (the process image of each of those cycles, one row each)."""
        records, images = self.engine.drain_samples(max_samples)
        image_len = self.layout.image_len if self.layout is not None else None
        return decode_samples(bytes(records), bytes(images), image_len)

    def decode_image(self, image: bytes | Any, slave: str | int) -> dict[str, Value]:
        """Inputs of one slave from a process image (e.g. a row of ``samples().images``)."""
        s = self.slave(slave)
        if s.layout is None or s.area is None:
            return {}
        a = s.area
        data = bytes(image[a.input_offset : a.input_offset + a.input_bytes])
        return s.layout.unpack(data, "input")

    def stats(self) -> dict[str, Any]:
        """The engine's counters and histograms (with ``frames``: per cyclic frame), ``groups``
        (per slave group, ``master/groups.py``) and the supervisor's counters."""
        out: dict[str, Any] = dict(self.engine.stats())
        out["groups"] = [g.as_dict() for g in self.group_stats(out)]
        if self.supervisor is not None:
            out["supervisor"] = self.supervisor.counters()
        return out

    def group_stats(self, engine_stats: dict[str, Any] | None = None) -> list[GroupStats]:
        """Each slave group's frames, rate, working counter and frame statistics."""
        if self.layout is None:
            return []
        stats = engine_stats if engine_stats is not None else dict(self.engine.stats())
        return group_stats(self.layout, stats, self.cycle_ns)

    # ---------------------------------------------------------------------------- safety
    def panic(self) -> None:
        """Safe outputs on the wire within two cycles, until ``clear_panic``."""
        self.engine.panic()

    def clear_panic(self) -> None:
        """End the panic without restarting anything (ISO 13850): the engine resets its output
        buffer to the safe image before it clears the latch, so every slave's outputs stay at
        their configured safe values until a new command for them arrives (a write changes
        only what it writes); CiA 402 axes follow their ``restart`` rule (manual: they wait
        for an explicit enable)."""
        with self._output_lock:
            self.engine.clear_panic()
            self._outputs = bytearray(self._safe)

    def reset_slave_outputs(self, s: Slave) -> None:
        """Slave ``s``'s outputs back to their configured safe values in the engine's buffer
        (not a command: no watchdog is fed). A slave that comes back to OP after it dropped
        out starts from them, not from what was commanded before it left."""
        area = s.area
        if not self._running or area is None or not area.output_bytes:
            return
        begin, end = area.output_offset, area.output_offset + area.output_bytes
        with self._output_lock:
            self.engine.reset_outputs(begin, end - begin)
            self._outputs[begin:end] = self._safe[begin:end]

    def feed_watchdog(self) -> None:
        self.engine.feed_watchdog()

    def stop_motion(self) -> None:
        """Stop what moves without leaving OP: every CiA 402 axis to its ``on_stop`` command and
        every slave's outputs to their configured safe values, as commands (unlike ``panic``
        nothing is latched: the next write moves again). The node does this when nobody holds
        the control lease any more."""
        if not self._running:
            return
        for i in range(len(self._axis_specs())):
            self.engine.axis_enable(i, False)
        if self._safe:
            with self._output_lock:
                self.engine.write_outputs(0, bytes(self._safe))
                self._outputs = bytearray(self._safe)

    # ---------------------------------------------------------------------------- acyclic
    def acyclic(self) -> threading.RLock:
        """The lock every acyclic exchange holds (bring-up, supervision, SDO and register
        access from the API, the ROS node and the tools through the claim), so that two of
        them never interleave their datagrams or a slave's mailbox messages."""
        return self._acyclic

    def states(self) -> list[SlaveState]:
        """Each slave's AL state and status code (read now, over the acyclic path)."""
        with self._acyclic:
            statuses = self.al.read([s.ref for s in self.slaves])
        return [_slave_state(s, st) for s, st in zip(self.slaves, statuses, strict=True)]

    def sdo_read(
        self, slave: str | int, index: int, subindex: int, dtype: str | None = None
    ) -> object:
        """Upload an object; typed by ``dtype`` (a type name) or the ESI dictionary, raw bytes
        when neither knows the type."""
        s = self.slave(slave)
        if s.sdo is None:
            raise BusError(f"{s}: has no CoE mailbox (start the bus first)")
        with self._acyclic:
            data: bytes = s.sdo.upload(index, subindex)
        t, bits = self._sdo_type(s, index, subindex, dtype)
        if t is None:
            return data
        if not bits or t.kind in ("string", "bytes"):
            bits = 8 * len(data)
        return dt.decode_value(t, data[: (bits + 7) // 8], bits)

    def sdo_write(
        self, slave: str | int, index: int, subindex: int, value: object, dtype: str | None = None
    ) -> None:
        s = self.slave(slave)
        if s.sdo is None:
            raise BusError(f"{s}: has no CoE mailbox (start the bus first)")
        data = bringup.encode_sdo_value(s, index, subindex, value, dtype)
        with self._acyclic:
            s.sdo.download(index, subindex, data)

    @staticmethod
    def _sdo_type(
        s: Slave, index: int, subindex: int, dtype: str | None
    ) -> tuple[dt.DataType | None, int]:
        if dtype:
            t = dt.config_type(dtype)
            if t is None:
                raise BusError(f"unknown data type {dtype!r}")
            return t, t.bit_length
        if s.device is not None:
            e = s.device.od_entry(index, subindex)
            if e is not None:
                return dt.BY_CODE.get(e.data_type), e.bit_length
        return None, 0

    # ---------------------------------------------------------------------------- events
    def on_event(self, callback: Callable[[BusEvent], None]) -> None:
        """Call ``callback`` (from the supervisor thread) for every supervision event."""
        self._listeners.append(callback)

    def emit(self, event: BusEvent) -> None:
        level = logging.WARNING if event.kind in ("slave_lost", "wkc_error") else logging.INFO
        log.log(level, "%s", event.message)
        for cb in list(self._listeners):
            try:
                cb(event)
            except Exception:  # a listener's bug must not stop supervision
                log.exception("bus event listener failed")

    def recover_slave(self, s: Slave) -> None:
        """Bring one slave back to OP after it dropped out (called by the supervisor). Its
        outputs start again from their safe values: what was commanded before it dropped out
        is not resumed by the recovery (a new command for it is)."""
        with self._acyclic:
            # First, so the cyclic frames carry the safe values for many cycles before the
            # slave reaches SAFEOP and OP (an ESC keeps the last output buffer it received).
            self.reset_slave_outputs(s)
            status = self.al.read([s.ref])[0]
            if not status.answered:
                self._readdress(s)
                status = self.al.read([s.ref])[0]
                if not status.answered:
                    raise BusError(f"{s}: does not answer")
            if status.error:
                self.al.acknowledge(s.ref, status)
            self.al.transition([s.ref], AlState.INIT)
            bringup.setup_mailbox(self.dg, s)
            self.al.transition([s.ref], AlState.PREOP)
            bringup.configure_preop(self.dg, s)
            if s.dc is not None and self.dc_reference is not None and self.dc_reference.dc:
                ref = self.dc_reference.dc
                # Re-sync from a DC slave that kept running: the reference, or (when the
                # reference itself was reset) the next healthy one, else the master's clock.
                source = ref if s.dc is not ref else None
                if source is None:
                    source = next(
                        (
                            o.dc
                            for o in self.slaves
                            if o.dc is not None and o is not s and not o.lost
                        ),
                        None,
                    )
                self.dc.resync_slave(source, s.dc)
                self.dc.activate_sync0([s.dc], self.cycle_ns, self._sync0_shift_ns, ref)
            self.al.transition([s.ref], AlState.SAFEOP)
            bringup.configure_safeop(self.dg, s)
            time.sleep(max(3 * self.cycle_ns / 1e9, 0.005))
            self.al.transition([s.ref], AlState.OP)

    def _readdress(self, s: Slave) -> None:
        """A slave that lost its station address (power cycle) gets it again by position —
        only if the slave now at that position has no other address: on a tree, a cable pulled
        on one branch moves the slaves of later branches up to lower positions."""
        from ether_ros.master.scan import count_slaves, station_address

        count = count_slaves(self.dg)
        if count <= s.position:
            raise BusError(f"{s}: not on the bus ({count} slaves answer)")
        data, wkc = self.dg.aprd(s.position, reg.STATION_ADDRESS, 2)
        current = int.from_bytes(data, "little") if wkc == 1 else 0
        if current not in (0, s.station):
            raise BusError(
                f"{s}: position {s.position} now holds station 0x{current:04X}: the slave is"
                " not where it was (a branch before it is cut off?)"
            )
        wkc = self.dg.apwr(
            s.position, reg.STATION_ADDRESS, station_address(s.position).to_bytes(2, "little")
        )
        if wkc != 1:
            raise BusError(f"{s}: re-assigning its station address failed")


def output_bit_offset(s: Slave, var: ProcessVariable) -> int:
    """Where output ``var`` of slave ``s`` starts in the process image, in bits."""
    assert s.area is not None
    return int(s.area.output_offset) * 8 + int(var.bit_offset)


def _output_field(s: Slave, var: ProcessVariable, raw: int) -> tuple[int, int, int]:
    """The image bit field (bit offset, bit length, raw) of output ``var`` of slave ``s``."""
    return (output_bit_offset(s, var), var.bit_length, raw)


def _slave_state(s: Slave, st: AlStatus) -> SlaveState:
    return SlaveState(
        name=s.name,
        position=s.position,
        station=s.station,
        state=st.name,
        error=st.error,
        code=st.code,
        text=al_code_text(st.code) if st.error else "",
        problem=s.last_problem if s.lost else "",
    )


def _load_config(config: Any) -> Any:
    if isinstance(config, str | Path):
        from ether_ros.config import load_bus_config

        return load_bus_config(config)
    return config


def _expected(cfg: Any, index: int) -> Expected:
    device = _device_for(None, cfg)
    vendor = cfg.vendor_id if cfg.vendor_id is not None else getattr(device, "vendor_id", None)
    product = cfg.product_code
    if product is None:
        product = getattr(device, "product_code", None)
    if vendor is None or product is None:
        raise ConfigError(f"slaves.{cfg.name}: no vendor_id/product_code and no ESI device")
    return Expected(
        name=cfg.name,
        vendor_id=int(vendor),
        product_code=int(product),
        revision=getattr(cfg, "revision", None),
        position=getattr(cfg, "position", None),
        alias=getattr(cfg, "alias", None),
    )


def _device_for(config: Any, slave_cfg: Any) -> EsiDevice | None:
    """The ESI device of a configured slave, as resolved by ``load_bus_config``."""
    dev = getattr(slave_cfg, "_esi", None)
    return dev if isinstance(dev, EsiDevice) else None


def iter_names(slaves: Iterable[Slave]) -> list[str]:
    return [s.name for s in slaves]
