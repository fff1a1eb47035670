"""Supervision rounds against a scripted bus (one layer down: AL statuses and engine counters
are scripted; the Supervisor's own logic is real)."""

from __future__ import annotations

import threading
from typing import Any

from ether_ros.errors import BusError, LinkError
from ether_ros.master.al import AlState, AlStatus, SlaveRef
from ether_ros.master.events import BusEvent
from ether_ros.master.groups import GroupStats
from ether_ros.master.supervisor import Supervisor, counter
from ether_ros.topology import Link, line


class FakeSlave:
    def __init__(self, position: int, name: str) -> None:
        self.position, self.name = position, name
        self.station = 0x1001 + position
        self.lost = False
        self.last_problem = ""
        self.recoveries = 0
        self.sdo = None

    @property
    def ref(self) -> SlaveRef:
        return SlaveRef(self.position, self.station, self.name)

    def __str__(self) -> str:
        return f"slave {self.position} ({self.name})"


class FakeBus:
    def __init__(self, names: tuple[str, ...] = ("a", "b"), tree: list[Link] | None = None) -> None:
        self.slaves = [FakeSlave(k, name) for k, name in enumerate(names)]
        self.tree = tree if tree is not None else line(len(names))
        self.wkc_errors = 0
        self.statuses = [AlStatus(AlState.OP, False, 0)] * len(names)
        self.link_up = True
        self.refuse = False
        self.recover_calls = 0
        self.events: list[BusEvent] = []
        self._acyclic = threading.RLock()
        self.layout = None
        # Per-group working-counter errors (name -> errors); empty: a bus without groups info.
        self.group_errors: dict[str, int] = {}
        bus = self

        class Engine:
            def stats(self) -> dict[str, Any]:
                return {"wkc_errors": bus.wkc_errors}

        class Al:
            def read(self, refs: list[SlaveRef]) -> list[AlStatus]:
                if not bus.link_up:
                    raise LinkError("no answer")
                return list(bus.statuses)

        # DL status per station: every port open with communication unless a test closes one.
        self.dl_status: dict[int, int] = {}

        class Dg:
            def fprd(self, station: int, ado: int, length: int) -> tuple[bytes, int]:
                assert ado == 0x0110
                return bus.dl_status.get(station, 0xAA00).to_bytes(2, "little"), 1

        self.engine, self.al, self.dg = Engine(), Al(), Dg()

    def group_stats(self, stats: dict[str, Any]) -> list[GroupStats]:
        return [
            GroupStats(name, 1, 1_000_000, (), (k,), 6, 6, 0, 0, 0, errors)
            for k, (name, errors) in enumerate(self.group_errors.items())
        ]

    def emit(self, event: BusEvent) -> None:
        self.events.append(event)

    def recover_slave(self, s: FakeSlave) -> None:
        self.recover_calls += 1
        if self.refuse:
            raise BusError(f"{s} refused OP: stays in SAFEOP")
        self.statuses[s.position] = AlStatus(AlState.OP, False, 0)

    def kinds(self) -> list[str]:
        return [e.kind for e in self.events]


def test_counter_flat_or_nested() -> None:
    assert counter({"wkc_errors": 3}, "wkc_errors") == 3
    assert counter({"counters": {"wkc_errors": 4}}, "wkc_errors") == 4
    assert counter({}, "wkc_errors") == 0


def test_wkc_errors_reported_once_per_burst() -> None:
    bus = FakeBus()
    sup = Supervisor(bus, recover_in_threads=False, retry_s=0)  # type: ignore[arg-type]
    for errors in (5, 9, 12, 12, 20):
        bus.wkc_errors = errors
        sup.check()
    assert bus.kinds() == ["wkc_error", "wkc_error"]
    assert bus.events[0].message.startswith("5 frame(s) with a wrong working counter")


def test_wkc_errors_are_reported_per_group() -> None:
    bus = FakeBus()
    bus.group_errors = {"default": 0, "io": 0}
    sup = Supervisor(bus, recover_in_threads=False, retry_s=0)  # type: ignore[arg-type]
    for errors in (3, 7, 7):
        bus.group_errors["io"] = errors
        sup.check()
    assert bus.kinds() == ["wkc_error"]
    assert bus.events[0].message == "group io: 3 frame(s) with a wrong working counter (expected 6)"
    bus.group_errors["default"] = 1
    sup.check()
    assert bus.events[-1].message.startswith("group default: 1 frame(s)")


def test_lost_slave_is_reported_then_recovered() -> None:
    bus = FakeBus()
    sup = Supervisor(bus, recover_in_threads=False, retry_s=0)  # type: ignore[arg-type]
    bus.statuses[1] = AlStatus(AlState.SAFEOP, True, 0x001B)
    bus.refuse = True
    sup.check()
    sup.check()
    assert bus.kinds() == ["slave_lost", "recovery_failed"]  # the same failure only once
    assert "SAFEOP + ERROR 0x001B (SyncManager watchdog" in bus.events[0].message
    assert (
        bus.events[1].message
        == "slave 1 (b): recovery failed: slave 1 (b) refused OP: stays in SAFEOP"
    )
    bus.refuse = False
    sup._next_try["b"] = 0.0
    sup.check()
    assert bus.kinds()[-1] == "slave_recovered"
    assert not bus.slaves[1].lost and bus.slaves[1].recoveries == 1


def test_link_lost_and_restored() -> None:
    bus = FakeBus()
    sup = Supervisor(bus, recover_in_threads=False, retry_s=0)  # type: ignore[arg-type]
    bus.link_up = False
    sup.check()
    sup.check()
    assert bus.kinds() == ["link_lost"]
    assert all(s.lost for s in bus.slaves)
    bus.link_up = True
    sup.check()
    assert bus.kinds() == ["link_lost", "link_restored", "slave_recovered", "slave_recovered"]


def test_a_cable_pulled_behind_a_junction_is_located() -> None:
    # coupler ─1─ io_a;  coupler ─2─ junction ─1─ io_b
    tree = [Link(None, 0), Link(0, 1), Link(0, 2), Link(2, 1)]
    bus = FakeBus(("coupler", "io_a", "junction", "io_b"), tree)
    bus.refuse = True  # recovery cannot reach them either
    sup = Supervisor(bus, recover_in_threads=False, retry_s=0)  # type: ignore[arg-type]
    silent = AlStatus(0, False, 0, answered=False)
    bus.statuses[2] = bus.statuses[3] = silent
    # The coupler still has a link on port 2: the junction is there but silent (power-cycled,
    # its station address gone), not cut off.
    sup.check()
    assert "branch_lost" not in bus.kinds()
    assert bus.slaves[3].last_problem == "does not answer"
    # Cable out: the coupler's port 2 loop is closed, no communication.
    bus.dl_status[0x1001] = 0xAA00 & ~(0x2000) | 0x1000
    sup.check()
    branch = [e for e in bus.events if e.kind == "branch_lost"]
    assert [e.message for e in branch] == [
        "link lost behind slave 'coupler' port 2: slaves junction, io_b unreachable"
    ]
    assert branch[0].slave == "junction"
    assert bus.slaves[3].last_problem == branch[0].message
    assert sup.branch_problems() == [branch[0].message]
    sup.check()
    assert bus.kinds().count("branch_lost") == 1, "reported once"
    bus.statuses[2] = bus.statuses[3] = AlStatus(AlState.OP, False, 0)
    sup.check()
    assert bus.kinds().count("branch_restored") == 1
    assert sup.branch_problems() == []
