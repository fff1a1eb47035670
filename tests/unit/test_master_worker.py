"""The acyclic worker: every user's requests share frames, each user gets its own replies, and
a slave that never answers does not stall the exchanges of the others."""

from __future__ import annotations

import threading

from ether_ros.master.datagrams import DatagramService
from ether_ros.master.worker import AcyclicWorker, run_in_parallel
from master_rigs import RecordingWire


def test_a_slow_slave_does_not_stall_the_others() -> None:
    """One user polls a slave that never answers, as a mailbox poll of a stalled slave does,
    until the other users are done; with a bus-wide lock around a slave's exchange the others
    would wait for it for ever."""
    wire = RecordingWire(silent=0x1001)
    worker = AcyclicWorker(wire)
    done = threading.Event()
    polls = [0]

    def slow() -> None:
        dg = worker.service()
        while not done.is_set():
            _data, wkc = dg.fprd(0x1001, 0x080D, 1)
            assert wkc == 0
            polls[0] += 1

    results: dict[int, list[bytes]] = {}

    def fast(dg: DatagramService, station: int) -> None:
        results[station] = [dg.fprd(station, 0x0130, 2)[0] for _ in range(20)]

    poller = threading.Thread(target=slow, daemon=True)
    poller.start()
    try:
        errors = run_in_parallel(worker, list(range(0x1002, 0x100A)), fast)
    finally:
        done.set()
        poller.join(timeout=30)
    assert errors == [None] * 8
    assert results == {s: [bytes([s & 0xFF]) * 2] * 20 for s in range(0x1002, 0x100A)}
    assert polls[0] > 0 and not poller.is_alive()
    # The slow slave's polls travelled in the same frames as the others' requests.
    shared = [f for f in wire.frames if {a & 0xFFFF for _c, a, _p in f} >= {0x1001, 0x1002}]
    assert shared


def test_rounds_batch_parallel_users_and_keep_each_users_order() -> None:
    wire = RecordingWire()
    worker = AcyclicWorker(wire)
    stations = list(range(0x1001, 0x1021))

    def work(dg: DatagramService, station: int) -> None:
        for k in range(4):
            assert dg.fpwr(station, 0x1000 + k, b"\x01") == 1

    assert run_in_parallel(worker, stations, work) == [None] * len(stations)
    assert worker.stats.frames == len(wire.frames)
    assert worker.stats.frames < len(stations) * 4 // 2
    for s in stations:
        mine = [a >> 16 for f in wire.frames for _c, a, _p in f if a & 0xFFFF == s]
        assert mine == [0x1000 + k for k in range(4)]


def test_a_lone_user_sends_at_once_in_its_own_thread() -> None:
    wire = RecordingWire()
    worker = AcyclicWorker(wire)
    dg = worker.service()
    assert dg.fprd(0x1005, 0x0130, 2) == (b"\x05\x05", 1)
    assert len(wire.frames) == 1 and worker.stats.rounds == 1


def test_a_slaves_mailbox_has_one_owner() -> None:
    worker = AcyclicWorker(RecordingWire())
    assert worker.mailbox(0x1001) is worker.mailbox(0x1001)
    assert worker.mailbox(0x1001) is not worker.mailbox(0x1002)
    assert worker.mailbox(0x1001).client("a") is None  # no mailbox set up yet
