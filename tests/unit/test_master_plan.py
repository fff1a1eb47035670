"""Process image layout, expected working counters, the engine plan, SM/FMMU encodings."""

from __future__ import annotations

import struct

import pytest

from ether_ros import _native
from ether_ros._native.protocol import fmmu
from ether_ros.master.datagrams import (
    DATAGRAM_OVERHEAD,
    FRAME_PAYLOAD,
    Cmd,
    Datagram,
    DatagramService,
)
from ether_ros.master.plan import (
    DcPlan,
    Frame,
    ImageLayout,
    ImageSlave,
    LogicalDatagram,
    RtPlan,
    build_plan,
    layout_image,
)
from ether_ros.master.sm_fmmu import Fmmu, SyncManager, mailbox_sms

LEGS = [(p, 0x1001 + p, f"leg{p}", 38, 22) for p in range(4)]


def test_outputs_of_all_slaves_then_inputs() -> None:
    layout = layout_image(LEGS)
    assert layout.output_bytes == 152 and layout.input_bytes == 88 and layout.image_len == 240
    assert [a.output_offset for a in layout.slaves] == [0, 38, 76, 114]
    assert [a.input_offset for a in layout.slaves] == [152, 174, 196, 218]
    # One frame, one LRW over the whole image.
    assert [f.datagrams for f in layout.frames] == [[LogicalDatagram("lrw", 0, 240, 0, 12)]]
    assert layout.expected_wkc == 4 * 3


def test_wkc_counts_only_directions_a_slave_has() -> None:
    layout = layout_image([(0, 0x1001, "out_only", 4, 0), (1, 0x1002, "in_only", 0, 2)])
    assert layout.expected_wkc == 2 + 1


def _frame_of_slaves(layout: ImageLayout, frame: Frame) -> set[str]:
    return {a.name for a in layout.slaves if a.frame == layout.frames.index(frame)}


def test_an_image_larger_than_a_frame_is_split_between_slaves() -> None:
    # 6 slaves of 300 + 300 bytes: two per frame (3 would need 1800 bytes).
    slaves = [(p, 0x1001 + p, f"s{p}", 300, 300) for p in range(6)]
    layout = layout_image(slaves, dc=True)
    assert len(layout.frames) == 3
    assert layout.frames[0].dc and not layout.frames[1].dc
    for k, f in enumerate(layout.frames):
        assert f.payload <= FRAME_PAYLOAD
        assert _frame_of_slaves(layout, f) == {f"s{2 * k}", f"s{2 * k + 1}"}
        # Outputs and inputs of the frame's two slaves: one LRW each, +2 per output area,
        # +1 per input area.
        assert [(d.command, d.length, d.expected_wkc) for d in f.datagrams] == [
            ("lrw", 600, 4),
            ("lrw", 600, 2),
        ]
    # No datagram cuts through a slave's area.
    for d in layout.datagrams:
        for a in layout.slaves:
            for off, n in ((a.output_offset, a.output_bytes), (a.input_offset, a.input_bytes)):
                inside = d.image_offset <= off and off + n <= d.image_offset + d.length
                outside = off + n <= d.image_offset or d.image_offset + d.length <= off
                assert inside or outside
    assert layout.expected_wkc == 6 * 3


def test_a_slave_larger_than_a_frame_gets_frames_of_its_own() -> None:
    layout = layout_image([(0, 1, "big", 2000, 1000), (1, 2, "small", 4, 4)])
    assert all(f.payload <= FRAME_PAYLOAD for f in layout.frames)
    big = layout.area("big")
    covered = sum(d.length for d in layout.datagrams if d.image_offset < 2000 + 4 + 1000)
    assert covered >= 3000
    # Every piece of the big slave's outputs counts its write FMMU (+2).
    pieces = [d for d in layout.datagrams if d.image_offset < big.output_bytes]
    assert len(pieces) == 2 and all(d.expected_wkc == 2 for d in pieces)
    assert layout.frames[layout.area("small").frame].expected_wkc == 3


def test_slaves_without_lrw_get_lwr_and_lrd_with_their_own_working_counters() -> None:
    slaves = [ImageSlave(0, 1, "a", 4, 2), ImageSlave(1, 2, "yaskawa", 8, 6, lrw=False),
              ImageSlave(2, 3, "b", 4, 2)]  # fmt: skip
    layout = layout_image(slaves)
    (frame,) = layout.frames
    # LWR of the LRD/LWR slave's outputs first, one LRW over the others' outputs and inputs,
    # then the LRD: LRW +2/+1 per slave, LWR and LRD +1.
    assert [(d.command, d.length, d.expected_wkc) for d in frame.datagrams] == [
        ("lwr", 8, 1),
        ("lrw", 12, 6),
        ("lrd", 6, 1),
    ]
    y = layout.area("yaskawa")
    assert (y.output_offset, y.input_offset) == (0, 16 + 4)
    assert layout.expected_wkc == 8


def test_groups_have_their_own_frames_and_rate() -> None:
    slaves = [ImageSlave(p, 0x1001 + p, f"s{p}", 10, 10, "io" if p % 2 else "default")
              for p in range(4)]  # fmt: skip
    layout = layout_image(slaves, groups=[("default", 1), ("io", 8)], dc=True)
    assert [(f.group, f.every, f.dc) for f in layout.frames] == [
        ("default", 1, True),
        ("io", 8, False),
    ]
    io = layout.group("io")
    assert io.slaves == ("s1", "s3") and io.frames == (1,) and io.every == 8
    assert layout.group_wkc("io") == 6 and layout.group_wkc("default") == 6
    # The group's outputs and inputs are contiguous (outputs first overall).
    assert [layout.area(n).output_offset for n in ("s0", "s2", "s1", "s3")] == [0, 10, 20, 30]
    # All slaves in a slow group: the DC datagrams get a frame of their own, every cycle.
    slow = layout_image(
        [ImageSlave(0, 1, "a", 2, 2, "io")], groups=[("default", 1), ("io", 4)], dc=True
    )
    assert [(f.every, f.dc, len(f.datagrams)) for f in slow.frames] == [(1, True, 0), (4, False, 1)]
    with pytest.raises(ValueError, match="nope"):
        layout_image([ImageSlave(0, 1, "a", 2, 2, "nope")])


def test_plan_follows_engine_contract() -> None:
    layout = layout_image(LEGS, dc=True)
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
    assert isinstance(plan, _native.Plan)
    (frame,) = plan.frames
    assert frame.every == 1 and frame.watchdog_ns == 0
    kinds = [d.kind for d in frame.datagrams]
    assert kinds == ["dc_write_ref", "dc_sync", "lrw"]
    lrw = frame.datagrams[2]
    assert isinstance(lrw, _native.LogicalDatagram)
    assert (lrw.address, lrw.length, lrw.image_offset, lrw.expected_wkc) == (0, 240, 0, 12)
    assert plan.output_ranges == [(0, 152)]
    assert plan.safe_image[:152] == safe and len(plan.safe_image) == 240
    assert (plan.dc.mode, plan.dc.time_offset_ns, plan.dc.sync0_shift_ns) == (
        "ref_follows_master", 123, 55_000,
    )  # fmt: skip
    # RtPlan's defaults (the only ones: RtSettings has none) reach the engine's type.
    assert (plan.rt.policy, plan.rt.priority, plan.rt.runtime_ns, plan.rt.lock_memory) == (
        "fifo", 80, 100_000, True,
    )  # fmt: skip
    follow = build_plan(layout, 400_000, "send_then_wait", safe, safe,
                        DcPlan("master_follows_ref", 0x1001), RtPlan(), 0)  # fmt: skip
    assert [d.kind for d in follow.frames[0].datagrams] == ["dc_sync", "lrw"]
    with pytest.raises(ValueError):
        build_plan(layout, 400_000, "sideways", safe, safe, DcPlan(), RtPlan(), 0)
    # A layout without room for the DC datagrams is refused, not sent oversized.
    with pytest.raises(ValueError, match="DC"):
        build_plan(layout_image(LEGS), 400_000, "send_at_wake", safe, safe,
                   DcPlan("ref_follows_master", 0x1001), RtPlan(), 0)  # fmt: skip


def test_a_groups_watchdog_goes_to_each_of_its_frames() -> None:
    slaves = [ImageSlave(p, 0x1001 + p, f"s{p}", 800, 10, "io" if p else "default")
              for p in range(3)]  # fmt: skip
    layout = layout_image(slaves, groups=[("default", 1), ("io", 2)])
    out = bytes(layout.output_bytes)
    plan = build_plan(layout, 1_000_000, "send_at_wake", out, out, DcPlan(), RtPlan(), 0,
                      group_watchdog_ns={"io": 50_000_000})  # fmt: skip
    frames = zip(layout.frames, plan.frames, strict=True)
    by_group = [(f.group, p.watchdog_ns) for f, p in frames]
    assert by_group == [("default", 0), ("io", 50_000_000), ("io", 50_000_000)]


@pytest.mark.netns  # the RT thread locks memory
def test_the_engine_accepts_every_plan_the_builder_makes() -> None:
    from ether_ros._native import Engine, SimNetwork

    slaves = [ImageSlave(p, 0x1001 + p, f"s{p}", 300, 300, "io" if p > 3 else "default", p != 2)
              for p in range(7)]  # fmt: skip
    layout = layout_image(slaves, groups=[("default", 1), ("io", 4)], dc=True)
    assert len(layout.frames) >= 3
    out = bytes(layout.output_bytes)
    plan = build_plan(layout, 1_000_000, "send_at_wake", out, out,
                      DcPlan("ref_follows_master", 0x1001), RtPlan("other", 0), 0)  # fmt: skip
    engine = Engine.open_sim(SimNetwork())
    try:
        engine.start_cyclic(plan)
        engine.stop_cyclic()
        frames = engine.stats()["frames"]
        assert [f["every"] for f in frames] == [f.every for f in layout.frames]
    finally:
        engine.close()


def test_sync_manager_and_fmmu_bytes() -> None:
    sm = SyncManager(2, 0x1100, 38, 0x64)
    assert sm.register == 0x0810
    assert sm.encode() == bytes([0x00, 0x11, 38, 0, 0x64, 0, 1, 0])
    assert SyncManager.decode(2, sm.encode()) == sm
    f = Fmmu(1, 152, 22, 0x1400, fmmu.READ)
    raw = f.encode()
    assert f.register == 0x0610 and len(raw) == 16
    assert struct.unpack_from("<IHBBHBBB", raw) == (152, 22, 0, 7, 0x1400, 0, 1, 1)
    assert Fmmu.decode(1, raw) == f
    mbx = mailbox_sms(0x1000, 128, 0x1080, 128)
    assert [(m.index, m.control) for m in mbx] == [(0, 0x26), (1, 0x22)]
    assert fmmu.WRITE == 2


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
