"""One configuration state machine per slave (as IgH's ``fsm_slave_config``), the same for
bring-up, recovery and inspection.

    address  the slave answers at its station address (re-assigned after a power cycle)
    init     INIT requested (an AL error acknowledged first)                  AL timeout 5 s
    mailbox  SM0/SM1 for the mailbox; the slave's mailbox owner set up again
    preop    PREOP requested                                                  AL timeout 3 s
    coe      ESI init commands (IP, PS), sdo_init, PDO assignment and mapping  1 s per exchange
    process  process-data SyncManagers and FMMUs
    dc       SYNC0 (bring-up: bus-wide between the phases; recovery: re-sync from a running clock)
    safeop   SAFEOP requested                                                 AL timeout 10 s
    so       ESI init commands (SO), OpOnly SyncManagers
    outputs  outputs valid: the cyclic frame carries the slave's outputs for a few cycles
    op       OP requested                                                     AL timeout 10 s

A step that fails raises :class:`SlaveStepError`: the slave, the step, what it does, its
timeout, the AL state the slave showed then and its AL status code, and the cause (the typed
error of the step: ``AlStateRefused``, ``SdoAbort``, ``MailboxTimeout``, ...).

Bring-up (``bring_up``) runs every slave's machine in parallel over the acyclic worker, in three
phases around what is bus-wide: ``address``..``process`` for every slave, the DC delay
measurement and SYNC0 of the whole bus, ``safeop``..``so``, the cyclic frame started, then
``outputs``..``op``. Recovery (``recover``) runs one slave's machine from ``address`` to ``op``
while the others keep cycling; inspection (``inspect``: the tools' bus opened without a running
master) takes a slave to PREOP, its mailbox usable: ``address``..``preop`` for a slave in INIT or
with an AL error, only the ``mailbox`` step's owner set-up (its SyncManagers live already, left
as they are) for one already in PREOP, SAFEOP, OP or BOOT without an error — an inspection never
takes a working slave down.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from ether_ros._native.protocol import reg
from ether_ros.errors import BusError, EtherRosError
from ether_ros.master import bringup
from ether_ros.master.al import TRANSITION_TIMEOUT_S, AlState, AlStateMachine, AlStatus
from ether_ros.master.datagrams import DatagramService
from ether_ros.master.worker import AcyclicWorker, run_in_parallel

if TYPE_CHECKING:
    from ether_ros.master.slave import Slave

#: How long one mailbox exchange of a configuration step may take (the SDO client's timeout).
MAILBOX_STEP_TIMEOUT_S = 1.0
#: How long re-addressing a slave may take: its answers to a few datagrams.
ADDRESS_TIMEOUT_S = 0.1


@dataclass(frozen=True)
class Step:
    """One step of the machine: the AL state it works in (or requests), its timeout, and what
    it does (for the error)."""

    name: str
    state: AlState
    timeout_s: float
    what: str


STEPS: tuple[Step, ...] = (
    Step("address", AlState.INIT, ADDRESS_TIMEOUT_S, "the slave answers at its station address"),
    Step("init", AlState.INIT, TRANSITION_TIMEOUT_S[AlState.INIT], "INIT requested"),
    Step("mailbox", AlState.INIT, MAILBOX_STEP_TIMEOUT_S, "mailbox SyncManagers SM0/SM1"),
    Step("preop", AlState.PREOP, TRANSITION_TIMEOUT_S[AlState.PREOP], "PREOP requested"),
    Step("coe", AlState.PREOP, MAILBOX_STEP_TIMEOUT_S,
         "CoE init commands, sdo_init, PDO assignment and mapping"),
    Step("process", AlState.PREOP, MAILBOX_STEP_TIMEOUT_S,
         "process-data SyncManagers and FMMUs"),
    Step("dc", AlState.PREOP, MAILBOX_STEP_TIMEOUT_S, "distributed clock SYNC0"),
    Step("safeop", AlState.SAFEOP, TRANSITION_TIMEOUT_S[AlState.SAFEOP], "SAFEOP requested"),
    Step("so", AlState.SAFEOP, MAILBOX_STEP_TIMEOUT_S,
         "CoE init commands of SAFEOP→OP, OpOnly SyncManagers"),
    Step("outputs", AlState.SAFEOP, 1.0, "outputs valid (the cyclic frame carries them)"),
    Step("op", AlState.OP, TRANSITION_TIMEOUT_S[AlState.OP], "OP requested"),
)  # fmt: skip
STEP = {s.name: s for s in STEPS}


class SlaveStepError(BusError):
    """A step of a slave's configuration failed: ``step``, its ``timeout_s``, the AL ``state``
    and status ``code`` the slave showed (``state`` None: it did not answer), and ``cause``."""

    def __init__(
        self, slave: str, step: Step, status: AlStatus | None, cause: BaseException
    ) -> None:
        self.step = step.name
        self.timeout_s = step.timeout_s
        self.state = status.state if status is not None and status.answered else None
        self.code = int(getattr(cause, "code", 0) or (status.code if status else 0) or 0)
        self.cause = cause
        text = cause.reason if isinstance(cause, BusError) and cause.slave == slave else str(cause)
        text = text.removeprefix(f"{slave}: ").removeprefix(f"{slave} ")
        shown = status.describe() if status is not None else "unknown"
        super().__init__(
            f"{text} [step {step.name}: {step.what}, timeout {step.timeout_s:g} s; AL status "
            f"{shown}]",
            slave=slave,
        )


@dataclass
class Hooks:
    """What the bus does for a slave's machine at the bus-wide points: ``dc`` (None: done
    bus-wide by ``bring_up``), ``outputs`` (until the slave's outputs are valid), and
    ``reset_outputs`` (the slave's outputs back to their safe values, recovery only)."""

    outputs: Callable[[Slave], None]
    dc: Callable[[Slave], None] | None = None
    reset_outputs: Callable[[Slave], None] | None = None


class SlaveFsm:
    """The configuration state machine of one slave, over the bus's acyclic worker."""

    def __init__(self, slave: Slave, worker: AcyclicWorker, hooks: Hooks) -> None:
        self.slave = slave
        self.worker = worker
        self.hooks = hooks
        self.dg: DatagramService = worker.service()
        self.al = AlStateMachine(self.dg)
        self.owner = worker.mailbox(slave.station)
        # False while an inspection attaches to a slave whose mailbox SyncManagers are live.
        self._write_sms = True
        self._run = {
            "address": self._address,
            "init": lambda: self._transition(AlState.INIT),
            "mailbox": self._mailbox,
            "preop": lambda: self._transition(AlState.PREOP),
            "coe": lambda: bringup.configure_coe(self.slave),
            "process": lambda: bringup.configure_process_data(self.dg, self.slave),
            "dc": self._dc,
            "safeop": lambda: self._transition(AlState.SAFEOP),
            "so": lambda: bringup.configure_safeop(self.dg, self.slave),
            "outputs": lambda: self.hooks.outputs(self.slave),
            "op": lambda: self._transition(AlState.OP),
        }

    def run(self, first: str, last: str) -> None:
        """Steps ``first`` to ``last`` in order; the slave's mailbox is this machine's
        meanwhile (other users' exchanges with it wait, other slaves' do not)."""
        names = [s.name for s in STEPS]
        steps = STEPS[names.index(first) : names.index(last) + 1]
        runtime = self.slave.runtime
        with self.owner.lock:
            for step in steps:
                runtime.step = step.name
                try:
                    self._run[step.name]()
                except EtherRosError as exc:
                    raise SlaveStepError(str(self.slave), step, self._status(), exc) from exc
            runtime.step = ""

    def inspect(self) -> None:
        """To PREOP with the mailbox usable, never down from a working state (module doc)."""
        status = self._status()
        live = status is not None and status.answered and status.state in _MAILBOX_LIVE
        if live and status is not None and not status.error:
            self._write_sms = False
            try:
                self.run("mailbox", "mailbox")
            finally:
                self._write_sms = True
            return
        self.run("address", "preop")

    def _status(self) -> AlStatus | None:
        try:
            return self.al.read([self.slave.ref])[0]
        except EtherRosError:
            return None

    def _transition(self, state: AlState) -> None:
        self.al.transition([self.slave.ref], state, STEP[_STEP_OF[state]].timeout_s)
        self.slave.runtime.al_state = int(state)

    def _mailbox(self) -> None:
        bringup.setup_mailbox(self.dg, self.slave, write=self._write_sms)
        s = self.slave
        self.owner.attach(s.mailbox, s.sdo_client)
        s.sdo = self.owner.client(s.name)

    def _dc(self) -> None:
        if self.hooks.dc is not None and self.slave.dc is not None:
            self.hooks.dc(self.slave)

    def _address(self) -> None:
        """A slave that lost its station address (power cycle) gets it again by position —
        only if the slave now at that position has no other address: on a tree, a cable pulled
        on one branch moves the slaves of later branches up to lower positions."""
        from ether_ros.master.scan import count_slaves, station_address

        s = self.slave
        if self.al.read([s.ref])[0].answered:
            return
        count = count_slaves(self.dg)
        if count <= s.position:
            raise BusError(f"not on the bus ({count} slaves answer)", slave=str(s))
        data, wkc = self.dg.aprd(s.position, reg.STATION_ADDRESS, 2)
        current = int.from_bytes(data, "little") if wkc == 1 else 0
        if current not in (0, s.station):
            raise BusError(
                f"position {s.position} now holds station 0x{current:04X}: the slave is not where"
                " it was (a branch before it is cut off?)",
                slave=str(s),
            )
        address = station_address(s.position).to_bytes(2, "little")
        if self.dg.apwr(s.position, reg.STATION_ADDRESS, address) != 1:
            raise BusError("re-assigning its station address failed", slave=str(s))
        if not self.al.read([s.ref])[0].answered:
            raise BusError("does not answer", slave=str(s))


#: States in which a slave's mailbox SyncManagers are set up already (by whoever took it there).
_MAILBOX_LIVE = (AlState.PREOP, AlState.SAFEOP, AlState.OP, AlState.BOOT)

_STEP_OF = {
    AlState.INIT: "init",
    AlState.PREOP: "preop",
    AlState.SAFEOP: "safeop",
    AlState.OP: "op",
}


def run_phase(
    worker: AcyclicWorker, slaves: Sequence[Slave], hooks: Hooks, first: str, last: str
) -> None:
    """Steps ``first``..``last`` of every slave's machine in parallel; raises the first failure
    in bus order (every slave's error is logged on its runtime)."""

    def work(_dg: DatagramService, s: Slave) -> None:
        SlaveFsm(s, worker, hooks).run(first, last)

    _raise_first(slaves, run_in_parallel(worker, slaves, work))


def _raise_first(slaves: Sequence[Slave], errors: Sequence[BaseException | None]) -> None:
    """Each slave's error on its runtime; the first failure in bus order raised, naming how
    many others failed."""
    for s, exc in zip(slaves, errors, strict=True):
        s.runtime.last_error = str(exc) if exc is not None else ""
    failed = [(s, e) for s, e in zip(slaves, errors, strict=True) if e is not None]
    if failed:
        first_error = failed[0][1]
        assert first_error is not None
        if len(failed) > 1:
            others = ", ".join(str(s) for s, _ in failed[1:])
            first_error.add_note(f"{len(failed) - 1} more slave(s) failed too: {others}")
        raise first_error


def bring_up(
    worker: AcyclicWorker,
    slaves: Sequence[Slave],
    hooks: Hooks,
    bus_dc: Callable[[], None],
    start_cyclic: Callable[[], None],
) -> None:
    """Every slave from wherever it is to OP, their machines in parallel: the three phases of
    the module doc, with the bus-wide DC set-up (``bus_dc``) and the cyclic frame
    (``start_cyclic``) between them."""
    run_phase(worker, slaves, hooks, "init", "process")
    bus_dc()
    run_phase(worker, slaves, hooks, "safeop", "so")
    start_cyclic()
    run_phase(worker, slaves, hooks, "outputs", "op")


def recover(worker: AcyclicWorker, slave: Slave, hooks: Hooks) -> None:
    """One slave that dropped out back to OP through the same machine, the others cycling.
    Its outputs start again from their safe values (set first, so the cyclic frames carry them
    for many cycles before the slave reaches SAFEOP: an ESC keeps the last outputs it got)."""
    if hooks.reset_outputs is not None:
        hooks.reset_outputs(slave)
    SlaveFsm(slave, worker, hooks).run("address", "op")


def inspect(worker: AcyclicWorker, slaves: Sequence[Slave]) -> None:
    """Inspection: every slave of ``slaves`` to PREOP with its mailbox set up, their machines
    in parallel (a slave already working is only attached to, module doc); raises the first
    failure in bus order."""
    hooks = Hooks(outputs=_no_outputs)

    def work(_dg: DatagramService, s: Slave) -> None:
        SlaveFsm(s, worker, hooks).inspect()

    errors = run_in_parallel(worker, slaves, work)
    _raise_first(slaves, errors)


def _no_outputs(_slave: Slave) -> None:
    """Inspection never reaches the ``outputs`` step (it stops at PREOP)."""


def outputs_after(cycles: int, cycle_ns: int, minimum_s: float) -> Callable[[Any], None]:
    """An ``outputs`` hook that waits ``cycles`` cycles (at least ``minimum_s``)."""

    def wait(_slave: Any) -> None:
        time.sleep(max(cycles * cycle_ns / 1e9, minimum_s))

    return wait
