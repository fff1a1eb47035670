"""Python calls into the protocol crate on hot paths (``ether_ros._native.protocol``): what one
call costs next to the pure-Python way measured in the same run.

1. Per-sample decoding in the ROS publisher: ``protocol.AreaDecoder`` decodes a slave's input
   area into floats for every published sample. The baseline is the decoder it replaced
   (one precompiled ``struct`` for byte-aligned numbers, shifts for bit fields), kept here as
   the reference.
2. Value checks of writes: ``config.types.to_raw`` (``Bus.write``, one Rust call for the range)
   and ``ros.values.check_value`` (every ROS write), against the bare Python comparison they
   replaced.
"""

from __future__ import annotations

import math
import random
import struct
import time
from collections.abc import Callable
from functools import partial
from pathlib import Path
from typing import Any

from report import Report

REPO = Path(__file__).resolve().parent.parent

_STRUCT_CODES = {
    ("int", 8): "b", ("uint", 8): "B", ("int", 16): "h", ("uint", 16): "H",
    ("int", 32): "i", ("uint", 32): "I", ("int", 64): "q", ("uint", 64): "Q",
    ("real", 32): "f", ("real", 64): "d",
}  # fmt: skip


class StructDecoder:
    """The baseline: the pure-Python decoder the ROS publisher used before."""

    def __init__(self, variables: Any) -> None:
        variables = list(variables)
        self.size = len(variables)
        aligned = []
        self._bits: list[tuple[int, int, int, int, int, bool]] = []
        for i, v in enumerate(variables):
            code = _STRUCT_CODES.get((v.dtype.kind, v.bit_length))
            if code is not None and v.bit_offset % 8 == 0:
                aligned.append((v.bit_offset // 8, code, i))
            else:
                first, last = v.bit_offset // 8, (v.bit_offset + v.bit_length - 1) // 8
                kind = v.dtype.kind == "int"
                self._bits.append((i, first, last + 1, v.bit_offset % 8, v.bit_length, kind))
        aligned.sort()
        fmt, pos, self._index = "<", 0, []
        for offset, code, i in aligned:
            fmt += "x" * (offset - pos) + code
            pos = offset + struct.calcsize("<" + code)
            self._index.append(i)
        self._struct = struct.Struct(fmt)

    def decode(self, area: bytes) -> list[float]:
        out = [0.0] * self.size
        for i, value in zip(self._index, self._struct.unpack_from(area), strict=True):
            out[i] = float(value)
        for i, begin, end, shift, length, signed in self._bits:
            raw = (int.from_bytes(area[begin:end], "little") >> shift) & ((1 << length) - 1)
            if signed and raw & (1 << (length - 1)):
                raw -= 1 << length
            out[i] = float(raw)
        return out


def python_to_raw(kind: str, name: str, value: object, bit_length: int) -> int:
    """The baseline: config.types.to_raw as it was in pure Python."""
    if isinstance(value, bool) or not isinstance(value, int):
        raise ValueError(f"{name} needs an integer, got {value!r}")
    if kind == "int":
        lo, hi = -(1 << (bit_length - 1)), (1 << (bit_length - 1)) - 1
    else:
        lo, hi = 0, (1 << bit_length) - 1
    if not lo <= value <= hi:
        raise ValueError(f"{value} is out of range for {name} [{lo}, {hi}]")
    return value & ((1 << bit_length) - 1)


def python_check(value: float, var: Any, by_name: dict[str, Any]) -> float:
    """The baseline: ros.values.check_value as it was in pure Python (its type lookup too)."""
    minimum, maximum = var.minimum, var.maximum
    if math.isnan(value) or math.isinf(value):
        raise ValueError("not a finite number")
    t = by_name.get(var.type.strip().lower())
    if t is None or t.kind in ("string", "bytes"):
        raise ValueError("unsupported data type")
    if t.kind in ("int", "uint", "bool") and not float(value).is_integer():
        raise ValueError("not an integer")
    if value < minimum or value > maximum:
        raise ValueError("outside")
    return float(value)


def decode_all(decoder: Any, areas: list[bytes]) -> None:
    for a in areas:
        decoder.decode(a)


def per_call_ns(fn: Callable[[], object], calls: int) -> float:
    """Best of five rounds, ns per call."""
    best = float("inf")
    for _ in range(5):
        start = time.perf_counter_ns()
        for _ in range(calls):
            fn()
        best = min(best, (time.perf_counter_ns() - start) / calls)
    return best


def run(report: Report) -> None:
    from ether_ros.config import load_bus_config
    from ether_ros.config import types as dt
    from ether_ros.ros import bridge
    from ether_ros.ros.layout import VariableSpec
    from ether_ros.ros.values import check_value

    calls = 2_000 if report.quick else 20_000
    rows = []
    for config in ("laelaps.yaml", "mixed.yaml"):
        cfg = load_bus_config(REPO / "config" / config)
        slave = max(cfg.slaves, key=lambda s: len(s.layout.inputs))
        variables = slave.layout.inputs
        rng = random.Random(1)
        areas = [bytes(rng.randrange(256) for _ in range(slave.layout.input_bytes))
                 for _ in range(64)]  # fmt: skip
        native, baseline = bridge.area_decoder(variables), StructDecoder(variables)
        assert all(native.decode(a) == baseline.decode(a) for a in areas)
        rounds = max(calls // len(areas), 1)
        n = per_call_ns(partial(decode_all, native, areas), rounds) / len(areas)
        b = per_call_ns(partial(decode_all, baseline, areas), rounds) / len(areas)
        rows.append([f"decode {slave.name} inputs ({len(variables)} variables)", f"{n:.0f}",
                     f"{b:.0f}", f"{n / b:.2f}"])  # fmt: skip
        report.value(f"decode_{config}", {"native_ns": n, "python_ns": b})

    lo, hi = -32768, 32767
    to_raw = per_call_ns(lambda: dt.to_raw(dt.INT16, 1234, 16), calls)
    old = per_call_ns(lambda: python_to_raw("int", "int16", 1234, 16), calls)
    rows.append(["to_raw int16 (Bus.write)", f"{to_raw:.0f}", f"{old:.0f}", f"{to_raw / old:.2f}"])
    var = VariableSpec("Kp", "int16", 0x7000, 1, 16, float(lo), float(hi))
    check = per_call_ns(lambda: check_value(1234.0, var), calls)
    old_check = per_call_ns(lambda: python_check(1234.0, var, dt.BY_NAME), calls)
    rows.append(["check_value int16 (ROS write)", f"{check:.0f}", f"{old_check:.0f}",
                 f"{check / old_check:.2f}"])  # fmt: skip
    report.value("to_raw_ns", {"native": to_raw, "python": old})
    report.value("check_value_ns", {"native": check, "python": old_check})
    report.text(
        "Python on the protocol crate (`ether_ros._native.protocol`), ns per call, best of five "
        "rounds; the baseline is the pure-Python code each call replaced, in the same run. "
        "Below 1.00 the native call is faster."
    )
    report.table(["what", "native ns", "python ns", "ratio"], rows)
