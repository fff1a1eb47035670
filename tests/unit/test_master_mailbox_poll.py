"""The acyclic worker polls idle mailboxes (``worker.py``): an emergency a slave raises while no
exchange with it is pending is read and routed to its owners, and a polling round carries the
SM1 status reads of every idle slave in shared frames, leaving a slave in an exchange alone."""

from __future__ import annotations

import threading
from typing import Any

from ether_ros._native import DriveFault
from ether_ros.config.bus import BusConfig
from ether_ros.master.datagrams import Cmd
from ether_ros.master.events import BusEvent
from ether_ros.master.mailbox import SM1_STATUS
from ether_ros.master.worker import AcyclicWorker
from ether_ros.testing.wait import wait_for
from master_rigs import relaxed_config, sim_bus


def _drives() -> BusConfig:
    cfg = relaxed_config("arm6.yaml")
    for s in cfg.slaves:
        s.sim.device = None  # the CiA 402 drive model: it can fault
        for a in s.axes:
            a.fault_reset = "manual"
    return cfg


def test_an_emergency_raised_while_no_sdo_is_pending_is_read_and_routed() -> None:
    with sim_bus(_drives()) as (bus, net):
        bus.start()
        assert bus.worker.polling
        drive = bus.slave(1)
        seen: list[Any] = []
        bus.worker.mailbox(drive.station).on_emergency.append(seen.append)
        events: list[BusEvent] = []
        bus.on_event(events.append)
        reads = bus.worker.stats.mailbox_reads
        # No SDO is pending: nobody but the worker's polling reads the mailbox (the supervisor
        # only reports what the worker read).
        net.inject(DriveFault(slave=1, error="encoder", axis=2))
        wait_for("the emergency routed to the mailbox's owner", lambda: bool(seen))
        assert seen[0].error_code == 0x7305 and seen[0].slave == drive.name
        assert bus.worker.stats.mailbox_reads > reads
        wait_for(
            "the supervisor's emergency event",
            lambda: any(e.kind == "emergency" and e.slave == drive.name for e in events),
        )
        assert any("0x7305" in e.message for e in events if e.kind == "emergency")
        bus.stop()
        assert not bus.worker.polling


class Wire:
    """SM1 status reads answer 'full' for ``full`` stations, 'empty' otherwise; records every
    frame."""

    def __init__(self, full: set[int]) -> None:
        self.full = full
        self.frames: list[list[tuple[int, int, bytes | int]]] = []

    def transact(
        self, datagrams: list[tuple[int, int, bytes | int]], timeout_us: int = 0,
        retries: int = 0,
    ) -> list[tuple[bytes, int]]:  # fmt: skip
        self.frames.append(list(datagrams))
        out = []
        for _cmd, address, payload in datagrams:
            station, ado = address & 0xFFFF, address >> 16
            n = payload if isinstance(payload, int) else len(payload)
            full = ado == SM1_STATUS and station in self.full
            out.append((bytes([0x08 if full else 0]) + bytes(n - 1), 1))
        return out


class Box:
    """A slave's mailbox as the worker's owner sees it: counts the reads of its read mailbox."""

    def __init__(self) -> None:
        self.reads = 0

    def poll_emergencies(self) -> None:
        self.reads += 1


def test_a_polling_round_shares_frames_and_skips_a_slave_in_an_exchange() -> None:
    stations = list(range(0x1001, 0x1011))
    wire = Wire(full={0x1003, 0x1005})
    worker = AcyclicWorker(wire)
    boxes = {}
    for st in stations:
        boxes[st] = Box()
        worker.mailbox(st).attach(boxes[st], None)
    worker.mailbox(0x1020)  # a slave without a mailbox: never polled
    busy = worker.mailbox(0x1005)
    with busy.lock:  # an exchange with 0x1005 runs in another thread: the poll leaves it alone
        result: list[int] = []
        t = threading.Thread(target=lambda: result.append(worker.poll_idle_mailboxes()))
        t.start()
        t.join(timeout=30)
    assert result == [1]
    assert len(wire.frames) == 1, "every idle slave's SM1 status in one frame"
    polled = {a & 0xFFFF for _c, a, _p in wire.frames[0]}
    assert polled == set(stations) - {0x1005}
    assert all(c == Cmd.FPRD and a >> 16 == SM1_STATUS for c, a, _p in wire.frames[0])
    assert [st for st, b in boxes.items() if b.reads] == [0x1003]
    assert worker.stats.mailbox_polls == 1 and worker.stats.mailbox_reads == 1
