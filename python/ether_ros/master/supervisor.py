"""Supervision during OP: a plain Python thread (never in the real-time path) that watches the
cyclic working counter and every slave's AL status, reports what goes wrong, and brings slaves
that dropped out of OP back by re-running their configuration once they answer again.

What it sees and does:
- working-counter errors counted by the engine: one ``wkc_error`` event per burst (a run of
  supervision rounds that each saw new errors);
- a slave not in OP, with an AL error, or not answering: ``slave_lost`` (once), then a recovery
  request every ``retry_s`` (backing off to ``max_retry_s``): the bus takes the slave through
  its state machine (``slave_fsm.py``: address, INIT, mailbox, PREOP configuration, DC
  re-sync, SAFEOP, OP) in a thread of its own, so a slave slow to come back delays neither
  the others' recoveries nor the watching; ``slave_recovered`` when it is back in OP;
- no answer at all (cable pulled): ``link_lost`` once, ``link_restored`` when frames return;
- a branch that stopped answering while the slave it hangs on still answers and shows no link
  on that port in its DL status (a cable pulled behind a junction): ``branch_lost`` once,
  naming the slave and port and the slaves cut off, ``branch_restored`` when they answer
  again;
- CoE emergency messages: ``emergency``, one per message, every round. The acyclic worker
  reads them (``worker.py``: its exchanges, and its polls of idle mailboxes) and the slave's SDO
  client keeps them; the supervisor only takes them (no mailbox read of its own), except after
  a failed recovery, when it reads the mailbox before the next attempt's INIT empties it.
"""

from __future__ import annotations

import logging
import threading
import time
from typing import Any, Protocol

from ether_ros._native.protocol import reg
from ether_ros.errors import BusError, EtherRosError
from ether_ros.master.al import AlState, AlStateMachine
from ether_ros.master.datagrams import DatagramService
from ether_ros.master.events import BusEvent
from ether_ros.master.groups import GroupStats
from ether_ros.master.slave import Slave
from ether_ros.topology import Link, behind, cut_branches, open_ports

log = logging.getLogger(__name__)


class SupervisedBus(Protocol):
    """What the supervisor needs of the bus (``ether_ros.master.bus.Bus``)."""

    engine: Any
    layout: Any
    dg: DatagramService
    al: AlStateMachine
    slaves: list[Slave]
    tree: list[Link]

    def recover_slave(self, s: Slave) -> None: ...

    def emit(self, event: BusEvent) -> None: ...

    def group_stats(self, engine_stats: dict[str, Any] | None = None) -> list[GroupStats]: ...


def branch_message(parent: Slave, port: int, cut_off: list[Slave]) -> str:
    """The report of a cable pulled on ``port`` of ``parent``."""
    names = ", ".join(s.name for s in cut_off)
    plural = "slave" if len(cut_off) == 1 else "slaves"
    return f"link lost behind slave '{parent.name}' port {port}: {plural} {names} unreachable"


def counter(stats: dict[str, Any], name: str) -> int:
    """A counter from the engine's stats, flat or under ``counters``."""
    if name in stats:
        return int(stats[name])
    inner = stats.get("counters")
    if isinstance(inner, dict) and name in inner:
        return int(inner[name])
    return 0


class Supervisor:
    def __init__(
        self,
        bus: SupervisedBus,
        period_s: float = 0.05,
        retry_s: float = 0.2,
        max_retry_s: float = 2.0,
        recover_in_threads: bool = True,
    ) -> None:
        self.bus = bus
        self.period_s = period_s
        self.retry_s = retry_s
        self.max_retry_s = max_retry_s
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="ether_ros-supervisor", daemon=True)
        # Working-counter errors seen so far and groups in a burst of them, per slave group.
        self._wkc_errors = {
            name: errors for name, (errors, _) in self._errors_by_group(bus.engine.stats()).items()
        }
        self._wkc_burst: set[str] = set()
        self._next_try: dict[str, float] = {}
        self._backoff: dict[str, float] = {}
        self._last_failure: dict[str, str] = {}
        # Recoveries under way (slave name → its thread and, once done, its error or None).
        self.recover_in_threads = recover_in_threads
        self._recovering: dict[str, tuple[threading.Thread, list[Any]]] = {}
        self.link_lost = False
        # Broken cables on branches: position of the first silent slave → (it, the report).
        self.cut_branches: dict[int, tuple[Slave, str]] = {}
        self.events = 0
        self.recoveries = 0

    def start(self) -> None:
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        if self._thread.is_alive() and threading.current_thread() is not self._thread:
            self._thread.join(timeout=30)
        for thread, _result in list(self._recovering.values()):
            thread.join(timeout=30)

    def branch_problems(self) -> list[str]:
        """The current broken-cable reports (for diagnostics)."""
        return [message for _slave, message in self.cut_branches.values()]

    def counters(self) -> dict[str, int]:
        return {"events": self.events, "recoveries": self.recoveries}

    def _emit(self, kind: str, slave: Slave | None, message: str) -> None:
        self.events += 1
        self.bus.emit(BusEvent(kind, slave.name if slave else None, message))

    def _run(self) -> None:
        while not self._stop.wait(self.period_s):
            try:
                self.check()
            except Exception:  # keep supervising whatever happens in one round
                log.exception("supervisor round failed")

    def check(self) -> None:
        """One supervision round (also callable directly, e.g. from tests)."""
        bus = self.bus
        self._check_wkc(dict(bus.engine.stats()))
        self._collect_recoveries()
        try:
            statuses = bus.al.read([s.ref for s in bus.slaves])
        except EtherRosError as exc:
            if not self.link_lost:
                self.link_lost = True
                self._emit("link_lost", None, f"the bus does not answer: {exc}")
                for s in bus.slaves:
                    s.lost = True
                    s.last_problem = "no answer (link down?)"
            return
        if self.link_lost:
            self.link_lost = False
            self._emit("link_restored", None, "frames come back again")
        self._locate_cuts([st.answered for st in statuses])
        now = time.monotonic()
        for s, st in zip(bus.slaves, statuses, strict=True):
            if s.name in self._recovering:
                continue  # its machine is running: it reports when done
            ok = st.answered and st.state == AlState.OP and not st.error
            if ok:
                if s.lost:
                    self._recovered(s, "back in OP")
                continue
            if not s.lost:
                s.lost = True
                s.last_problem = self._cut_behind(s) or st.describe()
                self._emit("slave_lost", s, f"{s} left OP: {st.describe()}")
                self._next_try[s.name] = now
                self._backoff[s.name] = self.retry_s
            if self._stop.is_set() or now < self._next_try.get(s.name, 0.0):
                continue
            self._try_recover(s)
        self._report_emergencies()

    def _locate_cuts(self, answered: list[bool]) -> None:
        """Report each branch that fell silent behind a slave that still answers (once), and
        each that answers again."""
        bus = self.bus
        if len(bus.tree) != len(bus.slaves):
            return
        by_position = {s.position: s for s in bus.slaves}
        heard = [True] * len(bus.tree)
        for s, ok in zip(bus.slaves, answered, strict=True):
            heard[s.position] = ok
        current: dict[int, tuple[Slave, str]] = {}
        for first, silent in cut_branches(bus.tree, heard):
            link = bus.tree[first]
            assert link.parent is not None
            if first in self.cut_branches:
                current[first] = self.cut_branches[first]
                continue
            if not self._port_closed(by_position[link.parent], link.port):
                continue  # still cabled: the slave is there but silent (e.g. power-cycled)
            cut_off = [by_position[k] for k in silent]
            message = branch_message(by_position[link.parent], link.port, cut_off)
            current[first] = (by_position[first], message)
            for s in cut_off:
                if s.lost:  # found silent before the cut was located
                    s.last_problem = message
        for first, (slave, message) in current.items():
            if first not in self.cut_branches:
                self._emit("branch_lost", slave, message)
        for first, (slave, message) in self.cut_branches.items():
            if first not in current:
                self._emit("branch_restored", slave, f"answering again (was: {message})")
        self.cut_branches = current

    def _port_closed(self, parent: Slave, port: int) -> bool:
        """The parent's DL status (0x0110) shows no link on ``port``: the cable is out (a
        slave that only lost its station address still has its link up)."""
        try:
            data, wkc = self.bus.dg.fprd(parent.station, reg.DL_STATUS, 2)
        except EtherRosError:
            return False
        return wkc == 1 and not open_ports(int.from_bytes(data, "little")) & (1 << port)

    def _cut_behind(self, s: Slave) -> str:
        """The broken-cable report that covers ``s`` ('' when none does)."""
        for first, (_slave, message) in self.cut_branches.items():
            if s.position in behind(self.bus.tree, first):
                return message
        return ""

    def _errors_by_group(self, stats: dict[str, Any]) -> dict[str, tuple[int, int | None]]:
        """(working-counter errors, expected working counter) per slave group; the engine's
        total under "" for a bus without a layout yet."""
        groups = self.bus.group_stats(stats)
        if not groups:
            return {"": (counter(stats, "wkc_errors"), None)}
        return {g.name: (g.wkc_errors, g.expected_wkc) for g in groups}

    def _check_wkc(self, stats: dict[str, Any]) -> None:
        """One ``wkc_error`` event per burst of bad cycles (a run of supervision rounds that
        each saw new errors), per slave group: a group whose slaves are gone is named alone."""
        now = self._errors_by_group(stats)
        for name, (errors, expected) in now.items():
            seen = self._wkc_errors.get(name, 0)
            if errors > seen and name not in self._wkc_burst:
                where = f"group {name}: " if len(now) > 1 else ""
                self._emit(
                    "wkc_error",
                    None,
                    f"{where}{errors - seen} frame(s) with a wrong working counter "
                    f"(expected {expected if expected is not None else '?'})",
                )
            if errors > seen:
                self._wkc_burst.add(name)
            else:
                self._wkc_burst.discard(name)
            self._wkc_errors[name] = errors

    def _report_emergencies(self) -> None:
        """The emergencies the worker read since the last round (a slave whose machine runs
        reports its own when it is done)."""
        for s in self.bus.slaves:
            if s.sdo is None or self._stop.is_set() or s.name in self._recovering:
                continue
            for em in s.sdo.take_emergencies():
                self._emit("emergency", s, em.text)

    def _read_emergencies(self, s: Slave) -> list[Any]:
        if s.sdo is None:
            return []
        try:
            return list(s.sdo.poll_emergencies())
        except EtherRosError as exc:
            log.debug("%s: polling emergencies failed: %s", s, exc)
            return []

    def _try_recover(self, s: Slave) -> None:
        """Request the slave's recovery: its machine runs in a thread of its own (or here,
        without ``recover_in_threads``); the result is taken by ``_collect_recoveries``."""
        result: list[Any] = [None, []]

        def run() -> None:
            try:
                self.bus.recover_slave(s)
            except BaseException as exc:  # handed to the supervisor's round
                result[0] = exc
                # A refusal usually comes with an emergency; read it now, before the next
                # attempt's INIT empties the mailbox (and before a later one arrives).
                result[1] = self._read_emergencies(s)

        if not self.recover_in_threads:
            run()
            self._recovery_done(s, result[0], result[1])
            return
        thread = threading.Thread(target=run, name=f"ether_ros-recover-{s.position}", daemon=True)
        self._recovering[s.name] = (thread, result)
        thread.start()

    def _collect_recoveries(self) -> None:
        by_name = {s.name: s for s in self.bus.slaves}
        for name, (thread, result) in list(self._recovering.items()):
            if thread.is_alive():
                continue
            del self._recovering[name]
            self._recovery_done(by_name[name], result[0], result[1])

    def _recovery_done(self, s: Slave, error: BaseException | None, emergencies: list[Any]) -> None:
        if error is not None and not isinstance(error, EtherRosError):
            log.error("%s: recovery failed", s, exc_info=error)
            error = BusError(f"recovery failed: {error}", slave=str(s))
        if isinstance(error, EtherRosError):
            exc = error
            backoff = min(self._backoff.get(s.name, self.retry_s) * 2, self.max_retry_s)
            self._backoff[s.name] = backoff
            self._next_try[s.name] = time.monotonic() + backoff
            # The reason without the slave's name when the error is about this slave.
            text = exc.reason if isinstance(exc, BusError) and exc.slave == str(s) else str(exc)
            if self._last_failure.get(s.name) != text:
                self._last_failure[s.name] = text
                self._emit("recovery_failed", s, f"{s}: recovery failed: {text}")
            for em in emergencies:
                self._emit("emergency", s, em.text)
            return
        self._recovered(s, "recovered to OP")

    def _recovered(self, s: Slave, how: str) -> None:
        s.lost = False
        s.recoveries += 1
        self.recoveries += 1
        self._last_failure.pop(s.name, None)
        self._emit("slave_recovered", s, f"{s} {how} (was: {s.last_problem})")
