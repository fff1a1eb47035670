"""The master's public face: open a bus from its configuration, bring it to OP, exchange process
data by variable name, and supervise it.

    bus = Bus.open("config/laelaps.yaml", interface="eth1")
    bus.start()                                   # INIT → PREOP → SAFEOP → OP, cyclic running
    bus.write("front_left_leg", "State_Machine", 1)
    bus.read("front_left_leg", "hip_angle")
    bus.stop(); bus.close()

A facade: the configured bus is ``setup.py`` (compiled once), the found one ``found.py``, bound
by ``bind.py``; every acyclic exchange goes through the bus's acyclic worker (``worker.py``, the
owner of every slave's mailbox); bring-up and recovery run each slave's state machine
(``slave_fsm.py``); the process image is ``image.py``; supervision ``supervisor.py``; the
engine's real-time thread runs the cyclic frame.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Iterable, Mapping
from types import TracebackType
from typing import Any

from ether_ros._native import Plan as EnginePlan
from ether_ros.claim import InterfaceClaim
from ether_ros.config.process import Value
from ether_ros.errors import BusError
from ether_ros.master import axis as axis_mod
from ether_ros.master import bind, bringup, lifecycle
from ether_ros.master.al import AlStateMachine
from ether_ros.master.dc import EPOCH_2000_S, DistributedClocks
from ether_ros.master.events import BusEvent
from ether_ros.master.found import SlaveState, slave_state
from ether_ros.master.groups import GroupStats, group_stats
from ether_ros.master.image import ProcessImage, StaleInputs, now_monotonic_ns, output_bit_offset
from ether_ros.master.samples import Samples, decode_samples
from ether_ros.master.setup import BusSetup
from ether_ros.master.slave import Slave
from ether_ros.master.supervisor import Supervisor
from ether_ros.master.worker import AcyclicWorker

log = logging.getLogger(__name__)
__all__ = ["Bus", "BusEvent", "SlaveState", "StaleInputs", "output_bit_offset"]


class Bus:
    """An EtherCAT bus driven by the engine; see the module doc."""

    def __init__(self, config: Any, engine: Any, drift_frames: int | None = None) -> None:
        self.setup = config if isinstance(config, BusSetup) else BusSetup.compile(config)
        self.config, self.engine, self.cycle_ns = self.setup.config, engine, self.setup.cycle_ns
        self.worker = AcyclicWorker(engine)  # the one owner of acyclic datagrams and mailboxes
        self.dg = self.worker.service()
        self.al = AlStateMachine(self.dg)
        self.slaves: list[Slave] = []
        self.tree: list[Any] = []  # where each slave hangs (by position), as found
        self.layout: Any = None
        self.plan: EnginePlan | None = None
        # DC system time = CLOCK_MONOTONIC + this: ns since 2000-01-01 (wall clock at open).
        self.time_offset_ns = time.time_ns() - now_monotonic_ns() - EPOCH_2000_S * 1_000_000_000
        frames = 3000 if drift_frames is None else drift_frames
        self.dc = DistributedClocks(self.dg, self.master_time, drift_frames=frames)
        self.dc_reference: Slave | None = None
        self._bound: bind.Bound | None = None
        self._acyclic = threading.RLock()  # whole-bus work: bring-up, stop
        self._running = self._closed = False
        self.image = ProcessImage(engine, self.slave, lambda: self._running, self.setup.axes)
        self._listeners: list[Callable[[BusEvent], None]] = []
        self.supervisor: Supervisor | None = None
        self.claim: InterfaceClaim | None = None  # the interface claimed (None: in-process)
        # Why a write from another process is refused now (None: allowed); the node sets it.
        self.remote_write_refusal: Callable[[], str | None] = lambda: None
        # Per engine axis, for this cyclic run: the mode last commanded, the number of the last
        # trajectory started and how it started (shared by every Axis object of the axis).
        self.axis_modes: dict[int, str] = {}
        self.axis_trajectories: dict[int, int] = {}
        self.axis_trajectory_starts: dict[int, axis_mod.TrajectoryStart] = {}

    @classmethod
    def open(
        cls, config: Any, interface: str | None = None, link: Any = None,
        drift_frames: int | None = None,
    ) -> Bus:  # fmt: skip
        """Open the link (``interface``, or ``link``: an in-process ``SimNetwork``), scan the
        bus and check it against the configuration. The slaves stay in INIT until ``start``."""
        return lifecycle.open_bus(cls, config, interface, link, drift_frames)

    def set_bound(self, bound: bind.Bound) -> None:  # the bus as bound (lifecycle.open_bus)
        self._bound, self.slaves, self.tree = bound, bound.slaves, bound.tree
        self.dc_reference, self.layout = bound.dc_reference, bound.layout
        self.image.bind(bound.layout, bound.slaves, bound.safe)

    def master_time(self) -> int:
        """The master's DC system time now (ns since 2000)."""
        now = getattr(self.engine, "now_ns", None)
        return (now() if now is not None else now_monotonic_ns()) + self.time_offset_ns

    # ---------------------------------------------------------------------------- start/stop
    @property
    def running(self) -> bool:
        return self._running

    @property
    def closed(self) -> bool:
        return self._closed

    @property
    def bound(self) -> bind.Bound | None:
        return self._bound

    def start(self) -> None:
        """Every slave's state machine to OP, in parallel (``slave_fsm.bring_up``), then
        supervise."""
        lifecycle.start(self)

    def stop(self) -> None:
        """Safe outputs on the wire, slaves to SAFEOP then INIT, cyclic exchange stopped."""
        lifecycle.stop(self)

    def set_running(self, running: bool) -> None:
        """The cyclic exchange started or stopped (``lifecycle``'s, not a command)."""
        self._running = running

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

    def __exit__(self, t: type[BaseException] | None, e: BaseException | None,
                 tb: TracebackType | None) -> None:  # fmt: skip
        self.close()

    def recover_slave(self, s: Slave) -> None:
        """One slave that dropped out back to OP through its state machine (requested by the
        supervisor) while the others keep cycling (``lifecycle.recover``)."""
        lifecycle.recover(self, s)

    # ---------------------------------------------------------------------------- slaves
    def slave(self, which: str | int) -> Slave:
        """A slave by configured name or bus position."""
        for s in self.slaves:
            if s.name == which or (isinstance(which, int) and s.position == which):
                return s
        names = ", ".join(s.name for s in self.slaves)
        raise BusError(f"no slave {which!r} on this bus (slaves: {names})")

    def states(self) -> list[SlaveState]:
        """Each slave's AL state and status code (read now, through the acyclic worker)."""
        statuses = self.al.read([s.ref for s in self.slaves])
        return [slave_state(s, st) for s, st in zip(self.slaves, statuses, strict=True)]

    def acyclic(self) -> threading.RLock:
        """The lock of whole-bus work (bring-up, stop); exchanges with one slave do not need
        it (the worker queues every datagram; each slave's mailbox has its own lock)."""
        return self._acyclic

    def sdo_read(self, slave: str | int, index: int, subindex: int,
                 dtype: str | None = None) -> object:  # fmt: skip
        """Upload an object; typed by ``dtype`` (a type name) or the ESI dictionary, raw bytes
        when neither knows the type."""
        return bringup.sdo_read(self.slave(slave), index, subindex, dtype)

    def sdo_write(self, slave: str | int, index: int, subindex: int, value: object,
                  dtype: str | None = None) -> None:  # fmt: skip
        bringup.sdo_write(self.slave(slave), index, subindex, value, dtype)

    # ---------------------------------------------------------------------------- process data
    def write(self, slave: str | int, variable: str, value: object) -> None:
        """Set one output; a bad variable, type or value raises before the wire."""
        self.write_many(slave, {variable: value})

    def write_many(self, slave: str | int, values: Mapping[str, object]) -> None:
        """Several outputs of one slave, in the same cycle; only these bits change."""
        self.image.write_slaves({slave: values})

    def write_slaves(self, values: Mapping[str | int, Mapping[str, object]]) -> None:
        """Outputs of several slaves, all checked (the device's own rule too) before any is
        written, all in the same cycle; a bad value changes nothing."""
        self.image.write_slaves(values)

    def write_all(self, variable: str, value: object) -> int:
        """``variable`` on every slave that has it as an output; returns how many."""
        return self.image.write_all(variable, value)

    def read(self, slave: str | int, variable: str, stale_ok: bool = False) -> Value:
        """An input as received (``StaleInputs`` when not fresh, unless ``stale_ok``) or an
        output as commanded."""
        return self.image.read(self.slave(slave), variable, stale_ok)

    def inputs(self, slave: str | int, stale_ok: bool = False) -> dict[str, Value]:
        return self.image.inputs(self.slave(slave), stale_ok)

    def outputs(self, slave: str | int) -> dict[str, Value]:
        return self.image.outputs(self.slave(slave))

    def input_frames(self, slave: str | int) -> tuple[int, ...]:
        """The cyclic frames that carry ``slave``'s process data."""
        return self.image.frames(self.slave(slave))

    def inputs_fresh(self, slave: str | int) -> bool:
        """Every frame carrying ``slave``'s inputs came back whole within two periods."""
        return self.image.fresh(self.slave(slave))

    def input_age(self, slave: str | int) -> float:
        """Seconds since ``slave``'s inputs last came back whole (inf: never, not running)."""
        return self.image.age(self.slave(slave))

    def decode_image(self, image: bytes | Any, slave: str | int) -> dict[str, Value]:
        """Inputs of one slave from a process image (e.g. a row of ``samples().images``)."""
        return self.image.decode(image, self.slave(slave))

    def samples(self, max_samples: int = 65536) -> Samples:
        """Drain the engine's per-cycle sample ring (``master/samples.py``)."""
        records, images = self.engine.drain_samples(max_samples)
        image_len = self.layout.image_len if self.layout is not None else None
        return decode_samples(bytes(records), bytes(images), image_len)

    def stats(self) -> dict[str, Any]:
        """The engine's counters, ``groups`` and the supervisor's counters."""
        out: dict[str, Any] = dict(self.engine.stats())
        out["groups"] = [g.as_dict() for g in self.group_stats(out)]
        if self.supervisor is not None:
            out["supervisor"] = self.supervisor.counters()
        return out

    def group_stats(self, engine_stats: dict[str, Any] | None = None) -> list[GroupStats]:
        if self.layout is None:
            return []
        stats = engine_stats if engine_stats is not None else dict(self.engine.stats())
        return group_stats(self.layout, stats, self.cycle_ns)

    # ---------------------------------------------------------------------------- safety
    def panic(self) -> None:
        """Safe outputs on the wire within two cycles, until ``clear_panic``."""
        self.engine.panic()

    def clear_panic(self) -> None:
        """End the panic without restarting anything (ISO 13850): outputs stay at their safe
        values until a new command; CiA 402 axes follow their ``restart`` rule."""
        self.image.clear_panic()

    def reset_slave_outputs(self, s: Slave) -> None:
        """``s``'s outputs back to their safe values in the engine's buffer (not a command)."""
        self.image.reset_slave(s)

    def feed_watchdog(self) -> None:
        self.engine.feed_watchdog()

    def stop_motion(self) -> None:
        """Every axis to its ``on_stop`` and every output to its safe value, as commands
        (nothing latched), without leaving OP."""
        if self._running:
            for i in range(len(self.setup.axes)):
                self.engine.axis_enable(i, False)
            self.image.to_safe(on_wire=True)

    # ---------------------------------------------------------------------------- axes
    def axes(self) -> list[axis_mod.Axis]:
        """Every CiA 402 axis of the bus (docs/cia402.md), in bus order."""
        return [axis_mod.Axis(self, i, spec) for i, spec in enumerate(self.setup.axes)]

    def axis(self, name: str) -> axis_mod.Axis:
        return axis_mod.find(self, name)

    def follow(self, tracks: Mapping[str, Iterable[axis_mod.TrajectoryPoint | tuple[float, ...]]],
               start_in: float = 0.0) -> float:  # fmt: skip
        """One trajectory for several axes by joint name, started in the same cycle."""
        return axis_mod.follow_named(self, tracks, start_in)

    def quiet_stop(self, names: Iterable[str] | None = None) -> None:
        axis_mod.quiet_stop_named(self, names)

    def wait_trajectories(self, names: Iterable[str] | None = None, timeout: float = 10.0) -> None:
        axis_mod.wait_named(self, names, timeout)

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
