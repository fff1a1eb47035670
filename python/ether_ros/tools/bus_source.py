"""Turn a running :class:`~ether_ros.master.bus.Bus` into what the tools consume.

``Bus.samples()`` hands over the engine's per-cycle records (a numpy structured array, see
``master/samples.py``) and the process image of each cycle. :class:`BusSampleSource` turns them
into :class:`~ether_ros.tools.recording.CycleData`, decoding variables only every
``decoded_decimation`` cycles: decoding is Python work, timing is not.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from ether_ros.tools.recording import (
    BusInfo,
    CycleData,
    CycleTiming,
    SlaveInfo,
    VariableInfo,
)

# Field names of the engine's sample record (crates/engine/src/handover.rs SampleRecord).
_TIMING_FIELDS = {
    "cycle": ("cycle",),
    "t_wake_ns": ("t_wake_ns",),
    "wake_latency_ns": ("wake_latency_ns", "latency_ns"),
    "exec_ns": ("exec_ns",),
    "period_ns": ("period_ns",),
    "rtt_ns": ("rtt_ns",),
    "working_counter": ("wkc", "working_counter"),
    "flags": ("flags",),
    "dc_diff_ns": ("dc_diff_ns",),
}


def _variable_info(var: Any) -> VariableInfo:
    rng = var.range()
    lo, hi = (float(rng[0]), float(rng[1])) if rng else (float("-inf"), float("inf"))
    return VariableInfo(var.name, var.dtype.name, var.index, var.subindex, var.bit_length, lo, hi)


def bus_info(bus: Any) -> BusInfo:
    """The recording's description of an opened bus: slaves and their variables."""
    slaves = []
    cycle_us = int(bus.config.bus.cycle_us)
    groups = getattr(getattr(bus, "layout", None), "groups", None) or []
    group_of = {name: (g.name, g.every * cycle_us) for g in groups for name in g.slaves}
    for s in bus.slaves:
        layout = s.layout
        inputs = tuple(_variable_info(v) for v in layout.inputs) if layout else ()
        outputs = tuple(_variable_info(v) for v in layout.outputs) if layout else ()
        device = getattr(s.device, "type_name", "") if s.device is not None else ""
        group, group_cycle_us = group_of.get(s.name, ("default", cycle_us))
        slaves.append(
            SlaveInfo(s.name, s.position, str(device), inputs, outputs, group, group_cycle_us)
        )
    return BusInfo(str(bus.config.bus.name), cycle_us, tuple(slaves))


def split_samples(samples: Any) -> tuple[Any, Any]:
    """``Bus.samples()`` → (records, images), whether it returns a ``Samples`` object or a
    pair."""
    if hasattr(samples, "records"):
        return samples.records, samples.images
    records, images = samples
    return records, images


def _column(records: Any, names: Sequence[str]) -> Any:
    available = records.dtype.names or ()
    for name in names:
        if name in available:
            return records[name]
    return None


class BusSampleSource:
    """Cycles and statistics of a running bus, for the :class:`Recorder` (non-RT thread)."""

    def __init__(self, bus: Any, decoded_decimation: int = 10, raw_decimation: int = 0) -> None:
        self.bus = bus
        self.decoded_decimation = max(1, decoded_decimation)
        self.raw_decimation = max(0, raw_decimation)
        self._areas = [
            (s.name, s.layout, s.area)
            for s in bus.slaves
            if s.layout is not None and s.area is not None
        ]
        self._expected_wkc = int(getattr(bus.layout, "expected_wkc", 0) or 0)

    def cycles(self) -> list[CycleData]:
        records, images = split_samples(self.bus.samples())
        n = len(records)
        if n == 0:
            return []
        columns = {key: _column(records, names) for key, names in _TIMING_FIELDS.items()}
        out: list[CycleData] = []
        for i in range(n):
            values = {k: (int(c[i]) if c is not None else 0) for k, c in columns.items()}
            data = CycleData(CycleTiming(**values), expected_wkc=self._expected_wkc)
            cycle = values["cycle"]
            image = bytes(images[i]) if images is not None and len(images) > i else b""
            if image and cycle % self.decoded_decimation == 0:
                for name, layout, area in self._areas:
                    ins = layout.unpack(
                        image[area.input_offset : area.input_offset + area.input_bytes], "input"
                    )
                    outs = layout.unpack(
                        image[area.output_offset : area.output_offset + area.output_bytes], "output"
                    )
                    data.inputs[name] = [float(v) for v in ins.values()]
                    data.outputs[name] = [float(v) for v in outs.values()]
            if image and self.raw_decimation and cycle % self.raw_decimation == 0:
                layout_img = self.bus.layout
                split = int(getattr(layout_img, "output_bytes", 0))
                data.raw_out, data.raw_in = image[:split], image[split:]
            out.append(data)
        return out

    def stats(self) -> dict[str, Any]:
        return dict(self.bus.stats())
