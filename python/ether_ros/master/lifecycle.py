"""The life of a bus: open (claim the interface, open the engine, scan and bind), start (every
slave's state machine to OP in parallel, with the bus-wide DC set-up and the cyclic frame
between its phases, ``slave_fsm.bring_up``), stop, and the recovery of one slave (its machine
again, ``slave_fsm.recover``). ``Bus`` (the facade) calls these.
"""

from __future__ import annotations

import logging
import time
from typing import TYPE_CHECKING, Any

from ether_ros.claim import InterfaceClaim
from ether_ros.errors import BusError, EtherRosError, LinkError
from ether_ros.master import axis as axis_mod
from ether_ros.master import bind, slave_fsm
from ether_ros.master.al import AlState
from ether_ros.master.link import open_engine
from ether_ros.master.scan import scan
from ether_ros.master.service import serve_bus
from ether_ros.master.setup import BusSetup
from ether_ros.master.supervisor import Supervisor

if TYPE_CHECKING:
    from ether_ros.master.bus import Bus
    from ether_ros.master.slave import Slave

log = logging.getLogger(__name__)

#: How long stop() gives the drives to leave Operation Enabled after their on_stop command.
AXIS_STOP_WAIT_S = 0.5


def open_bus(
    cls: type[Bus], config: Any, interface: str | None, link: Any, drift_frames: int | None
) -> Bus:
    from ether_ros import _native

    setup, claim = BusSetup.compile(config), None
    if link is not None:
        engine = _native.Engine.open_sim(link)
    else:
        ifname = interface or getattr(setup.config.bus, "interface", None)
        if not ifname:
            raise LinkError("no network interface: give --interface or bus.interface")
        # One master per interface: a second one would take the running one's slaves down to
        # INIT under it (docs/master.md, "One master per interface").
        claim = InterfaceClaim.take(ifname, "master")
        try:
            b = setup.config.bus
            engine = open_engine(ifname, b.link, b.busy_poll_us, qdisc_bypass=not b.capture)
        except BaseException:
            claim.release()
            raise
    bus = cls(setup, engine, drift_frames=drift_frames)
    try:
        with bus.acyclic():
            bus.set_bound(bind.bind(setup, scan(bus.dg)))
    except BaseException:
        engine.close()
        if claim is not None:
            claim.release()
        raise
    if claim is not None:
        bus.claim = claim
        serve_bus(claim, bus)
    return bus


def start(bus: Bus) -> None:
    """Every slave's machine to OP in parallel, then supervision."""
    if bus.closed:
        raise BusError("the bus is closed")
    if bus.running:
        return
    for d in (bus.axis_modes, bus.axis_trajectories, bus.axis_trajectory_starts):
        d.clear()
    sync0 = [0]

    def bus_dc() -> None:
        sync0[0] = _bus_dc(bus)

    def start_cyclic() -> None:
        assert bus.bound is not None
        bus.image.to_safe()  # the cyclic frame starts with the safe outputs
        bus.plan = bind.engine_plan(bus.setup, bus.bound, bus.time_offset_ns, bus.image.safe)
        bus.engine.start_cyclic(bus.plan)
        bus.set_running(True)

    def op_ready(_s: Slave) -> None:
        # Slaves check for valid outputs (and running SYNC0) before they accept OP.
        time.sleep(max(5 * bus.cycle_ns / 1e9, 0.01))
        while sync0[0] and bus.master_time() < sync0[0] + 2 * bus.cycle_ns:
            time.sleep(0.005)

    with bus.acyclic():
        # Slaves may have been power-cycled since open: scan again, check identities.
        bind.rebind(bus.setup, bus.slaves, scan(bus.dg))
        try:
            slave_fsm.bring_up(
                bus.worker, bus.slaves, slave_fsm.Hooks(outputs=op_ready), bus_dc, start_cyclic
            )
        except BaseException:
            if bus.running:
                _shutdown_cyclic(bus)
            raise
    # While it runs, the worker reads what idle slaves put into their mailboxes (emergencies)
    # and the supervisor reports them.
    bus.worker.start_polling(bus.setup.mailbox_poll_s)
    bus.supervisor = Supervisor(bus)
    bus.supervisor.start()


def _bus_dc(bus: Bus) -> int:
    """Delays measured on the whole tree, drift compensated, SYNC0 started for every DC slave;
    returns the SYNC0 start time (0: no DC)."""
    ref = bus.dc_reference.dc if bus.dc_reference is not None else None
    if ref is None:
        return 0
    dc_slaves = [s.dc for s in bus.slaves if s.dc is not None]
    bus.dc.measure(dc_slaves, bus.tree)
    bus.dc.compensate_drift(ref)
    return int(bus.dc.activate_sync0(dc_slaves, bus.cycle_ns, bus.setup.sync0_shift_ns, ref))


def stop(bus: Bus) -> None:
    """Safe outputs on the wire, slaves to SAFEOP then INIT, cyclic exchange stopped."""
    if not bus.running:
        return
    if bus.supervisor is not None:
        bus.supervisor.stop()
        bus.supervisor = None
    bus.worker.stop_polling()
    with bus.acyclic():
        axis_mod.stop_all(bus.engine, len(bus.setup.axes), AXIS_STOP_WAIT_S)
        bus.image.to_safe(on_wire=True)
        time.sleep(max(3 * bus.cycle_ns / 1e9, 0.005))
        refs = [s.ref for s in bus.slaves]
        try:
            bus.al.transition(refs, AlState.SAFEOP)
        except EtherRosError as exc:
            log.warning("stop: not every slave went to SAFEOP: %s", exc)
        _shutdown_cyclic(bus)
        try:
            bus.dc.deactivate([s.dc for s in bus.slaves if s.dc is not None])
            bus.al.transition(refs, AlState.INIT)
        except EtherRosError as exc:
            log.warning("stop: not every slave went to INIT: %s", exc)


def _shutdown_cyclic(bus: Bus) -> None:
    try:
        bus.engine.stop_cyclic()
    finally:
        bus.set_running(False)


def recover(bus: Bus, s: Slave) -> None:
    """One slave back to OP through its machine; its outputs start again from their safe
    values: what was commanded before it dropped out is not resumed (a new command is)."""
    hooks = slave_fsm.Hooks(
        outputs=slave_fsm.outputs_after(3, bus.cycle_ns, 0.005),
        dc=lambda slave: _resync_dc(bus, slave),
        reset_outputs=bus.reset_slave_outputs,
    )
    slave_fsm.recover(bus.worker, s, hooks)


def _resync_dc(bus: Bus, s: Slave) -> None:
    """Re-sync from a DC slave that kept running: the reference, or (when the reference itself
    was reset) the next healthy one, else the master's clock."""
    ref = bus.dc_reference.dc if bus.dc_reference is not None else None
    if s.dc is None or ref is None:
        return
    others = (o.dc for o in bus.slaves if o.dc is not None and o is not s and not o.lost)
    bus.dc.resync_slave(ref if s.dc is not ref else next(others, None), s.dc)
    bus.dc.activate_sync0([s.dc], bus.cycle_ns, bus.setup.sync0_shift_ns, ref)
