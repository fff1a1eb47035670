"""Bring-up work of several slaves in threads, their datagrams sharing frames."""

from __future__ import annotations

from typing import Any

import pytest

from ether_ros.errors import LinkError
from ether_ros.master.datagrams import Cmd, DatagramService, fixed_address
from ether_ros.master.shared_frames import SharedFrames, run_in_parallel
from master_rigs import RecordingWire


def _work(results: dict[int, list[bytes]]) -> Any:
    def work(dg: DatagramService, station: int) -> None:
        got = []
        for k in range(5):  # five round trips per slave, as an SDO exchange has a few
            dg.fpwr(station, 0x1000 + k, b"\x01")
            got.append(dg.fprd(station, 0x1100, 2)[0])
        results[station] = got

    return work


def test_workers_share_frames_and_each_gets_its_own_replies() -> None:
    wire = RecordingWire()
    results: dict[int, list[bytes]] = {}
    stations = list(range(0x1001, 0x1011))
    run_in_parallel(DatagramService(wire), stations, _work(results))
    assert results == {s: [bytes([s & 0xFF]) * 2] * 5 for s in stations}
    # 16 slaves × 10 round trips one after the other would be 160 frames.
    assert len(wire.frames) < 160 // 3
    assert max(len(f) for f in wire.frames) > 1
    # Every datagram of a slave went out in its order.
    for s in stations:
        mine = [d for f in wire.frames for d in f if d[1] & 0xFFFF == s]
        assert [d[1] >> 16 for d in mine] == [a for k in range(5) for a in (0x1000 + k, 0x1100)]


def test_a_failure_reaches_its_worker_and_the_caller() -> None:
    wire = RecordingWire(fail_station=0x1003)
    results: dict[int, list[bytes]] = {}
    with pytest.raises(LinkError, match="no answer"):
        run_in_parallel(DatagramService(wire), [0x1001, 0x1002, 0x1003], _work(results))


def test_a_frame_never_exceeds_the_budget() -> None:
    wire = RecordingWire()
    shared = SharedFrames(wire, 1)
    big = [(int(Cmd.FPRD), fixed_address(0x1001, 0x1000), 1000)]
    assert len(shared.transact(big)) == 1
    assert len(wire.frames) == 1
