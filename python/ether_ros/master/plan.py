"""The process image and the plan the engine runs cyclically.

Image layout (one LRW frame): the outputs of all slaves in bus order, then the inputs of all
slaves in bus order. Logical address = image offset (the image starts at logical address 0).
Outputs first keeps everything Python writes in one contiguous range at the front of the image,
which is the one range the engine copies from the output buffer each cycle.

If the image is longer than one datagram can carry it is cut into several LRW datagrams; each
one's expected working counter counts the slaves whose output area (+2) or input area (+1) it
touches — an LRW increments by 2 for every write FMMU it hits and by 1 for every read FMMU.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

from ether_ros.master.datagrams import MAX_DATAGRAM_DATA

LOGICAL_BASE = 0


@dataclass(frozen=True)
class SlaveArea:
    """Where one slave's process data sits in the image."""

    position: int
    station: int
    name: str
    output_offset: int
    output_bytes: int
    input_offset: int
    input_bytes: int


@dataclass(frozen=True)
class LrwChunk:
    address: int
    length: int
    image_offset: int
    expected_wkc: int


@dataclass
class ImageLayout:
    slaves: list[SlaveArea]
    output_bytes: int
    input_bytes: int
    chunks: list[LrwChunk] = field(default_factory=list)

    @property
    def image_len(self) -> int:
        return self.output_bytes + self.input_bytes

    @property
    def expected_wkc(self) -> int:
        return sum(c.expected_wkc for c in self.chunks)

    def area(self, name: str) -> SlaveArea:
        for s in self.slaves:
            if s.name == name:
                return s
        raise KeyError(name)


def layout_image(
    slaves: Sequence[tuple[int, int, str, int, int]], max_chunk: int = MAX_DATAGRAM_DATA
) -> ImageLayout:
    """``slaves``: (position, station, name, output bytes, input bytes) in bus order."""
    total_out = sum(s[3] for s in slaves)
    areas: list[SlaveArea] = []
    out_off, in_off = 0, total_out
    for position, station, name, nout, nin in slaves:
        areas.append(SlaveArea(position, station, name, out_off, nout, in_off, nin))
        out_off += nout
        in_off += nin
    layout = ImageLayout(areas, total_out, in_off - total_out)
    start = 0
    while start < layout.image_len:
        end = min(start + max_chunk, layout.image_len)
        wkc = 0
        for a in areas:
            if a.output_bytes and _overlaps(a.output_offset, a.output_bytes, start, end):
                wkc += 2
            if a.input_bytes and _overlaps(a.input_offset, a.input_bytes, start, end):
                wkc += 1
        layout.chunks.append(LrwChunk(LOGICAL_BASE + start, end - start, start, wkc))
        start = end
    return layout


def _overlaps(offset: int, length: int, start: int, end: int) -> bool:
    return offset < end and start < offset + length


@dataclass
class DcPlan:
    mode: str = "off"  # 'off' | 'ref_follows_master' | 'master_follows_ref'
    reference_station: int | None = None
    time_offset_ns: int = 0
    sync0_shift_ns: int = 0


@dataclass
class RtPlan:
    policy: str = "fifo"
    priority: int = 80
    cpu: int | None = None
    runtime_ns: int = 100_000
    lock_memory: bool = True


def build_plan(
    layout: ImageLayout,
    cycle_ns: int,
    order: str,
    safe_outputs: bytes,
    initial_outputs: bytes,
    dc: DcPlan,
    rt: RtPlan,
    watchdog_ns: int,
    ring_capacity: int = 65536,
    axes: list[dict[str, Any]] | None = None,
    trajectory_capacity: int = 1024,
) -> dict[str, Any]:
    """The dict ``Engine.start_cyclic`` takes (see the engine's plan contract)."""
    if len(safe_outputs) != layout.output_bytes or len(initial_outputs) != layout.output_bytes:
        raise ValueError("safe/initial output images must cover exactly the output area")
    if order not in ("send_at_wake", "send_then_wait"):
        raise ValueError(f"unknown cycle order {order!r}")
    datagrams: list[dict[str, Any]] = []
    if dc.mode != "off" and dc.reference_station is not None:
        if dc.mode == "ref_follows_master":
            datagrams.append({"kind": "dc_write_ref", "station": dc.reference_station})
        datagrams.append({"kind": "dc_sync", "station": dc.reference_station})
    for c in layout.chunks:
        datagrams.append(
            {
                "kind": "lrw",
                "address": c.address,
                "length": c.length,
                "image_offset": c.image_offset,
                "expected_wkc": c.expected_wkc,
            }
        )
    inputs_zero = bytes(layout.input_bytes)
    return {
        "cycle_ns": int(cycle_ns),
        "order": order,
        "datagrams": datagrams,
        "image_len": layout.image_len,
        "output_ranges": [(0, layout.output_bytes)] if layout.output_bytes else [],
        "initial_image": bytes(initial_outputs) + inputs_zero,
        "safe_image": bytes(safe_outputs) + inputs_zero,
        "dc": {
            "mode": dc.mode,
            "time_offset_ns": int(dc.time_offset_ns),
            "sync0_shift_ns": int(dc.sync0_shift_ns),
        },
        "rt": {
            "policy": rt.policy,
            "priority": rt.priority,
            "cpu": rt.cpu,
            "runtime_ns": rt.runtime_ns,
            "lock_memory": rt.lock_memory,
        },
        "watchdog_ns": int(watchdog_ns),
        "ring_capacity": int(ring_capacity),
        # CiA 402 axes (master/axis.py plan_entries): the engine's axis stage.
        "axes": list(axes or []),
        "trajectory_capacity": int(trajectory_capacity),
    }
