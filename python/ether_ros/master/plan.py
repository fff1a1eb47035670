"""The process image and the plan the engine runs cyclically: the one place that decides which
datagram goes in which frame.

Image layout: the outputs of all slaves, then the inputs of all slaves, each block ordered by
group (the default group first), then by frame, then — inside a frame — slaves that take LRD +
LWR before (outputs) or after (inputs) those that take LRW, each in bus order. Logical address
= image offset (the image starts at logical address 0). Outputs first keeps everything Python
writes in one contiguous range at the front of the image.

Frames: the slaves of a group are packed into as few frames as hold them, in bus order; a frame
never splits a slave's area unless that slave alone is larger than a frame. A frame carries one
datagram per contiguous run of its slaves' areas: LRW for the outputs and inputs of LRW slaves
(one datagram when they are adjacent, as in a one-frame bus), LWR for the outputs and LRD for
the inputs of slaves that refuse LRW (ESC register 0x0008 bit 9, or ``lrw: false`` in the
config). The DC datagrams ride in the first frame, which goes out every cycle; a group whose
cycle is n base cycles has frames with ``every = n``.

Expected working counters (ESC datasheet): LRW +2 for every slave whose output area it writes
and +1 for every slave whose input area it reads; LWR and LRD +1 per slave.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any, NamedTuple

from ether_ros import _native
from ether_ros.config.bus import DEFAULT_GROUP
from ether_ros.master.datagrams import DATAGRAM_OVERHEAD, FRAME_PAYLOAD

LOGICAL_BASE = 0
#: Bytes the two DC datagrams (FPWR and FRMW of 8 bytes each) take in the first frame.
DC_DATAGRAM_BYTES = 2 * (DATAGRAM_OVERHEAD + 8)


class ImageSlave(NamedTuple):
    """What the layout needs to know of one slave (bus order is the order given)."""

    position: int
    station: int
    name: str
    output_bytes: int
    input_bytes: int
    group: str = DEFAULT_GROUP
    lrw: bool = True


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
    group: str = DEFAULT_GROUP
    #: Index of the frame that carries it (the first one when it needs several).
    frame: int = 0
    lrw: bool = True


@dataclass(frozen=True)
class LogicalDatagram:
    command: str  # 'lrw' | 'lrd' | 'lwr'
    address: int
    length: int
    image_offset: int
    expected_wkc: int

    def to_plan(self) -> _native.LogicalDatagram:
        return _native.LogicalDatagram(
            kind=self.command,
            address=self.address,
            length=self.length,
            image_offset=self.image_offset,
            expected_wkc=self.expected_wkc,
        )


@dataclass
class Frame:
    """One cyclic frame: its logical datagrams, whether it carries the DC datagrams, and how
    often it goes out (in base cycles)."""

    group: str
    every: int
    datagrams: list[LogicalDatagram] = field(default_factory=list)
    dc: bool = False

    @property
    def expected_wkc(self) -> int:
        return sum(d.expected_wkc for d in self.datagrams)

    @property
    def payload(self) -> int:
        """Bytes of EtherCAT payload (without the 2-byte frame header)."""
        dc = DC_DATAGRAM_BYTES if self.dc else 0
        return dc + sum(DATAGRAM_OVERHEAD + d.length for d in self.datagrams)


@dataclass(frozen=True)
class Group:
    """A set of slaves with its own cycle (``every`` base cycles) and frames."""

    name: str
    every: int
    slaves: tuple[str, ...]
    frames: tuple[int, ...]


@dataclass
class ImageLayout:
    slaves: list[SlaveArea]
    output_bytes: int
    input_bytes: int
    frames: list[Frame] = field(default_factory=list)
    groups: list[Group] = field(default_factory=list)

    @property
    def image_len(self) -> int:
        return self.output_bytes + self.input_bytes

    @property
    def expected_wkc(self) -> int:
        """Working counter of all frames together (one cycle in which every frame goes out)."""
        return sum(f.expected_wkc for f in self.frames)

    @property
    def datagrams(self) -> list[LogicalDatagram]:
        return [d for f in self.frames for d in f.datagrams]

    def area(self, name: str) -> SlaveArea:
        for s in self.slaves:
            if s.name == name:
                return s
        raise KeyError(name)

    def group(self, name: str) -> Group:
        for g in self.groups:
            if g.name == name:
                return g
        raise KeyError(name)

    def frames_of(self, name: str) -> tuple[int, ...]:
        """The frames that carry slave ``name``'s process data (several when it is larger than
        one frame)."""
        area = self.area(name)
        return tuple(k for k, f in enumerate(self.frames) if _carries(f, area))

    def group_wkc(self, name: str) -> int:
        return sum(self.frames[k].expected_wkc for k in self.group(name).frames)


def layout_image(
    slaves: Sequence[tuple[Any, ...]],
    groups: Sequence[tuple[str, int]] = ((DEFAULT_GROUP, 1),),
    frame_payload: int = FRAME_PAYLOAD,
    dc: bool = False,
) -> ImageLayout:
    """Lay out the image and the frames. ``slaves``: ``ImageSlave`` tuples (or their first
    five fields: position, station, name, output bytes, input bytes) in bus order; ``groups``:
    (name, every) in plan order; ``dc``: room for the DC datagrams in the first frame."""
    pd = [ImageSlave(*s) for s in slaves]
    unknown = sorted({s.group for s in pd} - {name for name, _ in groups})
    if unknown:
        raise ValueError(f"slaves name groups that do not exist: {', '.join(unknown)}")
    # Frames of slaves, group by group; the first frame has room for the DC datagrams.
    frames: list[Frame] = []
    members: list[list[ImageSlave]] = []
    for name, n in groups:
        first_room = frame_payload - (DC_DATAGRAM_BYTES if dc and not frames else 0)
        for chunk in _pack([s for s in pd if s.group == name], first_room, frame_payload):
            frames.append(Frame(name, n, dc=not frames and dc))
            members.append(chunk)
    if dc and (not frames or frames[0].every != 1):
        # The DC datagrams go out every cycle: in a frame of their own if need be.
        if frames:
            frames[0].dc = False
        frames.insert(0, Frame(DEFAULT_GROUP, 1, dc=True))
        members.insert(0, [])
    # Offsets: outputs in frame order (LWR slaves first), then inputs (LRD slaves last).
    total_out = sum(s.output_bytes for s in pd)
    out_at: dict[str, int] = {}
    in_at: dict[str, int] = {}
    offset = 0
    for chunk in members:
        for s in sorted(chunk, key=lambda s: s.lrw):
            out_at[s.name] = offset
            offset += s.output_bytes
    for chunk in members:
        for s in sorted(chunk, key=lambda s: not s.lrw):
            in_at[s.name] = offset
            offset += s.input_bytes
    areas = [
        SlaveArea(s.position, s.station, s.name, out_at[s.name], s.output_bytes,
                  in_at[s.name], s.input_bytes, s.group, 0, s.lrw)
        for s in pd
    ]  # fmt: skip
    by_name = {a.name: a for a in areas}
    for frame, chunk in zip(frames, members, strict=True):
        frame.datagrams = _datagrams([by_name[s.name] for s in chunk], areas)
    # A frame left without datagrams (its slaves have no process data) is dropped, except the
    # one carrying the DC datagrams. When no frame is left at all, one LRD of a byte that no
    # slave maps (the last image byte, belonging to no slave; working counter 0) keeps the
    # cyclic frame going round the bus: a bus without process data runs too, and a lost
    # frame or a broken link is still seen every cycle.
    frames = [f for f in frames if f.datagrams or f.dc]
    if not frames:
        heartbeat = LogicalDatagram("lrd", LOGICAL_BASE + offset, 1, offset, 0)
        frames = [Frame(DEFAULT_GROUP, 1, datagrams=[heartbeat])]
        offset += 1
    layout = ImageLayout(areas, total_out, offset - total_out)
    layout.frames = _split_oversized(frames, frame_payload, areas)
    layout.slaves = [
        replace(a, frame=next(k for k, f in enumerate(layout.frames) if _carries(f, a)))
        if a.output_bytes or a.input_bytes else a
        for a in areas
    ]  # fmt: skip
    layout.groups = [
        Group(
            name,
            n,
            tuple(s.name for s in pd if s.group == name),
            tuple(k for k, f in enumerate(layout.frames) if f.group == name and f.datagrams),
        )
        for name, n in groups
    ]
    return layout


def _cost(chunk: Sequence[ImageSlave]) -> int:
    """Payload bytes the datagrams of ``chunk`` take at most: the LWR, LRW (outputs), LRW
    (inputs) and LRD runs, each with its header (the two LRW runs merge only in a one-frame
    bus, so they are counted apart)."""
    runs = [
        sum(s.output_bytes for s in chunk if not s.lrw),
        sum(s.output_bytes for s in chunk if s.lrw),
        sum(s.input_bytes for s in chunk if s.lrw),
        sum(s.input_bytes for s in chunk if not s.lrw),
    ]
    return sum(runs) + DATAGRAM_OVERHEAD * sum(1 for r in runs if r)


def _pack(
    slaves: Sequence[ImageSlave], first_room: int, frame_payload: int
) -> list[list[ImageSlave]]:
    """Slaves in bus order into as few frames as hold them (``first_room`` bytes in the first,
    ``frame_payload`` in the others); a slave too large for a frame gets a frame of its own
    (split later)."""
    chunks: list[list[ImageSlave]] = []
    current: list[ImageSlave] = []
    room = first_room
    for s in slaves:
        if current and _cost([*current, s]) > room:
            chunks.append(current)
            current = []
            room = frame_payload
        current.append(s)
    if current:
        chunks.append(current)
    return chunks


def _datagrams(chunk: Sequence[SlaveArea], areas: Sequence[SlaveArea]) -> list[LogicalDatagram]:
    """The logical datagrams of one frame's slaves: contiguous runs of their areas."""
    runs: list[tuple[str, int, int]] = []  # (command, image offset, length)
    for cmd, spans in (
        ("lwr", [(a.output_offset, a.output_bytes) for a in chunk if not a.lrw]),
        ("lrw", [(a.output_offset, a.output_bytes) for a in chunk if a.lrw]
                + [(a.input_offset, a.input_bytes) for a in chunk if a.lrw]),
        ("lrd", [(a.input_offset, a.input_bytes) for a in chunk if not a.lrw]),
    ):  # fmt: skip
        for off, n in sorted(spans):
            if not n:
                continue
            if runs and runs[-1][0] == cmd and runs[-1][1] + runs[-1][2] == off:
                runs[-1] = (cmd, runs[-1][1], runs[-1][2] + n)
            else:
                runs.append((cmd, off, n))
    return [_datagram(cmd, off, n, areas) for cmd, off, n in runs]


def _datagram(cmd: str, start: int, length: int, areas: Sequence[SlaveArea]) -> LogicalDatagram:
    """A logical datagram of image bytes ``start..start+length`` and its working counter."""
    end = start + length
    wkc = 0
    for a in areas:
        if cmd != "lrd" and _overlaps(a.output_offset, a.output_bytes, start, end):
            wkc += 2 if cmd == "lrw" else 1
        if cmd != "lwr" and _overlaps(a.input_offset, a.input_bytes, start, end):
            wkc += 1
    return LogicalDatagram(cmd, LOGICAL_BASE + start, length, start, wkc)


def _split_oversized(
    frames: list[Frame], frame_payload: int, areas: Sequence[SlaveArea]
) -> list[Frame]:
    """Frames over the budget (one slave larger than a frame) cut into several, each datagram
    cut where the frame is full; the working counters are counted per piece."""
    out: list[Frame] = []
    for f in frames:
        if f.payload <= frame_payload:
            out.append(f)
            continue
        current = Frame(f.group, f.every, dc=f.dc)
        for d in f.datagrams:
            off, left = d.image_offset, d.length
            while left:
                room = frame_payload - current.payload - DATAGRAM_OVERHEAD
                if room <= 0:
                    out.append(current)
                    current = Frame(f.group, f.every)
                    continue
                n = min(room, left)
                current.datagrams.append(_datagram(d.command, off, n, areas))
                off += n
                left -= n
        out.append(current)
    return out


def _carries(frame: Frame, area: SlaveArea) -> bool:
    return any(
        _overlaps(area.output_offset, area.output_bytes, d.image_offset, d.image_offset + d.length)
        or _overlaps(area.input_offset, area.input_bytes, d.image_offset, d.image_offset + d.length)
        for d in frame.datagrams
    )


def _overlaps(offset: int, length: int, start: int, end: int) -> bool:
    return length > 0 and offset < end and start < offset + length


@dataclass
class DcPlan:
    """The master's DC decision (``reference_station`` places the DC datagrams); the engine
    gets it as ``_native.DcSettings``. The defaults here are the only ones."""

    mode: str = "off"  # 'off' | 'ref_follows_master' | 'master_follows_ref'
    reference_station: int | None = None
    time_offset_ns: int = 0
    sync0_shift_ns: int = 0


@dataclass
class RtPlan:
    """The RT thread's scheduling as the master decides it; the engine gets it as
    ``_native.RtSettings``, which has no defaults: these are the only ones."""

    policy: str = "fifo"
    priority: int = 80
    cpu: int | None = None
    runtime_ns: int = 100_000
    lock_memory: bool = True


#: Sample ring records unless the caller says otherwise (the one default: the engine has none).
RING_CAPACITY = 65536


def build_plan(
    layout: ImageLayout,
    cycle_ns: int,
    order: str,
    safe_outputs: bytes,
    initial_outputs: bytes,
    dc: DcPlan,
    rt: RtPlan,
    watchdog_ns: int,
    ring_capacity: int = RING_CAPACITY,
    axes: Sequence[_native.AxisPlan] = (),
    trajectory_capacity: int | None = None,
    group_watchdog_ns: Mapping[str, int] | None = None,
) -> _native.Plan:
    """The ``_native.Plan`` ``Engine.start_cyclic`` runs (checked when made: an error names
    the field); ``group_watchdog_ns``: a group's own command watchdog, given to each of its
    frames; ``trajectory_capacity`` None: the engine's default."""
    if len(safe_outputs) != layout.output_bytes or len(initial_outputs) != layout.output_bytes:
        raise ValueError("safe/initial output images must cover exactly the output area")
    if order not in ("send_at_wake", "send_then_wait"):
        raise ValueError(f"unknown cycle order {order!r}")
    datagrams: list[list[_native.LogicalDatagram | _native.DcDatagram]] = [
        [d.to_plan() for d in f.datagrams] for f in layout.frames
    ]
    if dc.mode != "off" and dc.reference_station is not None:
        if not layout.frames or not layout.frames[0].dc:
            raise ValueError("the image layout has no room for the DC datagrams (layout_image dc)")
        dc_datagrams = [_native.DcDatagram(kind="dc_sync", station=dc.reference_station)]
        if dc.mode == "ref_follows_master":
            dc_datagrams.insert(
                0, _native.DcDatagram(kind="dc_write_ref", station=dc.reference_station)
            )
        datagrams[0][:0] = dc_datagrams
    watchdogs = group_watchdog_ns or {}
    frames = [
        # A group without a watchdog of its own: 0, none.
        _native.Frame(datagrams=dgs, every=f.every, watchdog_ns=int(watchdogs.get(f.group, 0)))
        for dgs, f in zip(datagrams, layout.frames, strict=True)
    ]
    inputs_zero = bytes(layout.input_bytes)
    return _native.Plan(
        cycle_ns=int(cycle_ns),
        order=order,
        frames=frames,
        image_len=layout.image_len,
        output_ranges=[(0, layout.output_bytes)] if layout.output_bytes else [],
        initial_image=bytes(initial_outputs) + inputs_zero,
        safe_image=bytes(safe_outputs) + inputs_zero,
        dc=_native.DcSettings(
            mode=dc.mode,
            time_offset_ns=int(dc.time_offset_ns),
            sync0_shift_ns=int(dc.sync0_shift_ns),
        ),
        rt=_native.RtSettings(
            policy=rt.policy,
            priority=rt.priority,
            cpu=rt.cpu,
            runtime_ns=rt.runtime_ns,
            lock_memory=rt.lock_memory,
        ),
        watchdog_ns=int(watchdog_ns),
        ring_capacity=int(ring_capacity),
        # CiA 402 axes (master/axis.py plan_entries): the engine's axis stage.
        axes=list(axes),
        trajectory_capacity=trajectory_capacity,
    )
