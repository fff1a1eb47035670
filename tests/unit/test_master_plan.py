"""Process image layout, expected working counters, the engine plan, SM/FMMU encodings."""

from __future__ import annotations

import struct

import pytest

from ether_ros.master.datagrams import (
    DATAGRAM_OVERHEAD,
    FRAME_PAYLOAD,
    Cmd,
    Datagram,
    DatagramService,
)
from ether_ros.master.plan import DcPlan, RtPlan, build_plan, layout_image
from ether_ros.master.sm_fmmu import FMMU_READ, FMMU_WRITE, Fmmu, SyncManager, mailbox_sms

LEGS = [(p, 0x1001 + p, f"leg{p}", 38, 22) for p in range(4)]


def test_outputs_of_all_slaves_then_inputs() -> None:
    layout = layout_image(LEGS)
    assert layout.output_bytes == 152 and layout.input_bytes == 88 and layout.image_len == 240
    assert [a.output_offset for a in layout.slaves] == [0, 38, 76, 114]
    assert [a.input_offset for a in layout.slaves] == [152, 174, 196, 218]
    assert len(layout.chunks) == 1
    assert layout.expected_wkc == 4 * 3


def test_wkc_counts_only_directions_a_slave_has() -> None:
    layout = layout_image([(0, 0x1001, "out_only", 4, 0), (1, 0x1002, "in_only", 0, 2)])
    assert layout.expected_wkc == 2 + 1


def test_large_image_is_split_and_each_chunk_counts_the_fmmus_it_touches() -> None:
    slaves = [(p, 0x1001 + p, f"s{p}", 300, 300) for p in range(4)]
    layout = layout_image(slaves, max_chunk=1000)
    assert [c.length for c in layout.chunks] == [1000, 1000, 400]
    # chunk 0: outputs of s0..s3 (0..1200 → s0,s1,s2,s3 partially) → 4 write FMMUs
    assert layout.chunks[0].expected_wkc == 2 * 4
    # chunk 1 (1000..2000): s3 outputs tail (900..1200) + inputs of s0..s2 (1200..2100)
    assert layout.chunks[1].expected_wkc == 2 + 3 * 1
    assert layout.chunks[2].expected_wkc == 2


def test_plan_dict_follows_engine_contract() -> None:
    layout = layout_image(LEGS)
    safe = bytes(range(152))
    plan = build_plan(
        layout,
        cycle_ns=400_000,
        order="send_at_wake",
        safe_outputs=safe,
        initial_outputs=safe,
        dc=DcPlan("ref_follows_master", 0x1001, 123, 55_000),
        rt=RtPlan(),
        watchdog_ns=100_000_000,
    )
    kinds = [d["kind"] for d in plan["datagrams"]]
    assert kinds == ["dc_write_ref", "dc_sync", "lrw"]
    assert plan["datagrams"][2] == {
        "kind": "lrw", "address": 0, "length": 240, "image_offset": 0, "expected_wkc": 12,
    }  # fmt: skip
    assert plan["output_ranges"] == [(0, 152)]
    assert plan["safe_image"][:152] == safe and len(plan["safe_image"]) == 240
    assert plan["dc"] == {"mode": "ref_follows_master", "time_offset_ns": 123,
                          "sync0_shift_ns": 55_000}  # fmt: skip
    follow = build_plan(layout, 400_000, "send_then_wait", safe, safe,
                        DcPlan("master_follows_ref", 0x1001), RtPlan(), 0)  # fmt: skip
    assert [d["kind"] for d in follow["datagrams"]] == ["dc_sync", "lrw"]
    with pytest.raises(ValueError):
        build_plan(layout, 400_000, "sideways", safe, safe, DcPlan(), RtPlan(), 0)


def test_sync_manager_and_fmmu_bytes() -> None:
    sm = SyncManager(2, 0x1100, 38, 0x64)
    assert sm.register == 0x0810
    assert sm.encode() == bytes([0x00, 0x11, 38, 0, 0x64, 0, 1, 0])
    assert SyncManager.decode(2, sm.encode()) == sm
    f = Fmmu(1, 152, 22, 0x1400, FMMU_READ)
    raw = f.encode()
    assert f.register == 0x0610 and len(raw) == 16
    assert struct.unpack_from("<IHBBHBBB", raw) == (152, 22, 0, 7, 0x1400, 0, 1, 1)
    assert Fmmu.decode(1, raw) == f
    mbx = mailbox_sms(0x1000, 128, 0x1080, 128)
    assert [(m.index, m.control) for m in mbx] == [(0, 0x26), (1, 0x22)]
    assert FMMU_WRITE == 2


class Recorder:
    def __init__(self) -> None:
        self.frames: list[list[tuple[int, int, bytes | int]]] = []

    def transact(self, datagrams, timeout_us=0, retries=0):  # type: ignore[no-untyped-def]
        self.frames.append(list(datagrams))
        return [(bytes(p if isinstance(p, int) else len(p)), 1) for _c, _a, p in datagrams]


def test_batch_splits_into_frames_that_fit() -> None:
    rec = Recorder()
    dg = DatagramService(rec)
    n = 3 * FRAME_PAYLOAD // (100 + DATAGRAM_OVERHEAD)
    replies = dg.batch([Datagram(Cmd.FPRD, i, 100) for i in range(n)])
    assert len(replies) == n
    assert len(rec.frames) >= 3
    for frame in rec.frames:
        assert sum(int(p) + DATAGRAM_OVERHEAD for _c, _a, p in frame) <= FRAME_PAYLOAD  # type: ignore[call-overload]
    assert [a for f in rec.frames for _c, a, _p in f] == list(range(n))
