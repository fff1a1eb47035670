"""The process image seen from Python: output writes by variable name (every value checked
before any reaches the wire), input and output reads, freshness of inputs, and the safe
outputs.

While the bus runs the engine's buffers are the truth (other writers, e.g. a native command
thread, change them too); this keeps Python's copy of the output image, what the plan starts
from and what reads of outputs return while not running. Output writes are bit fields merged
by the engine (``write_output_fields``), so a write never undoes another writer's variables.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Mapping, Sequence
from typing import Any

from ether_ros.config.cia402 import AxisSpec
from ether_ros.config.process import ProcessValueError, ProcessVariable, Value, write_bits
from ether_ros.errors import BusError
from ether_ros.master import axis as axis_mod
from ether_ros.master import workspace
from ether_ros.master.plan import ImageLayout
from ether_ros.master.slave import Slave

# A late wake-up of the cyclic thread on a busy host leaves a frame without its whole reply for
# a few cycles: a read waits this long for a fresh reply before it calls the inputs stale (a
# cable pulled or a slave cut off stays stale and is reported then).
STALE_GRACE_S = 0.05


class StaleInputs(BusError):
    """Inputs that are not fresh: the bus is not running, or no reply to the frame carrying
    the slave's inputs came back whole (every working counter as expected) within two of its
    periods — a cable pulled, the slave cut off or gone. Names the slave and since when."""


def now_monotonic_ns() -> int:
    return time.clock_gettime_ns(time.CLOCK_MONOTONIC)


def output_bit_offset(s: Slave, var: ProcessVariable) -> int:
    """Where output ``var`` of slave ``s`` starts in the process image, in bits."""
    assert s.area is not None
    return int(s.area.output_offset) * 8 + int(var.bit_offset)


class ProcessImage:
    """Reads and writes of one bus's process image (module doc)."""

    def __init__(
        self,
        engine: object,
        find: Callable[[str | int], Slave],
        running: Callable[[], bool],
        axes: Sequence[AxisSpec],
    ) -> None:
        self.engine: Any = engine
        self._find = find
        self._running = running
        self._axes = list(axes)
        self.layout: ImageLayout | None = None
        self.slaves: list[Slave] = []
        self.safe = b""
        # Serialises output writes so the mirror changes in the engine's order.
        self._lock = threading.Lock()
        self.mirror = bytearray()
        # Image byte → axis name of the output bytes the engine's axis stage owns (lazily).
        self._axis_owned: dict[int, str] | None = None

    def bind(self, layout: ImageLayout, slaves: Sequence[Slave], safe: bytes) -> None:
        self.layout, self.slaves, self.safe = layout, list(slaves), safe
        self.mirror = bytearray(safe)

    def to_safe(self, on_wire: bool = False) -> None:
        """The mirror (and with ``on_wire`` the engine's buffer) back to the safe image."""
        with self._lock:
            if on_wire and self.safe:
                self.engine.write_outputs(0, bytes(self.safe))
            self.mirror = bytearray(self.safe)

    # -- writes ---------------------------------------------------------------------------------
    def write_slaves(self, values: Mapping[str | int, Mapping[str, object]]) -> None:
        fields: list[tuple[int, int, int]] = []
        for slave, slave_values in values.items():
            fields.extend(self._checked_fields(self._find(slave), slave_values))
        self._write_fields(fields)

    def write_all(self, variable: str, value: object) -> int:
        targets = [
            s
            for s in self.slaves
            if s.layout is not None
            and s.layout.has(variable)
            and s.layout.variable(variable, "output").direction == "output"
        ]
        if not targets:
            raise ProcessValueError(f"no slave has an output variable {variable!r}")
        self.write_slaves({s.name: {variable: value} for s in targets})
        return len(targets)

    def variable(self, slave: Slave, name: str, direction: str | None = None) -> ProcessVariable:
        if slave.layout is None:
            raise BusError(f"{slave}: has no process data")
        try:
            return slave.layout.variable(name, direction)
        except ProcessValueError as exc:
            raise ProcessValueError(f"{slave}: {exc}") from None

    def _checked_fields(self, s: Slave, values: Mapping[str, object]) -> list[tuple[int, int, int]]:
        """The output fields of ``values`` for slave ``s``, every one checked."""
        area = s.area
        if s.layout is None or area is None or not area.output_bytes:
            raise BusError(f"{s}: has no outputs")
        variables: list[ProcessVariable] = []
        for name in values:
            var = self.variable(s, name, "output")
            if var.direction != "output":
                raise ProcessValueError(f"{s}: variable {name!r} is an input, not an output")
            self._refuse_axis_owned(s, var)
            variables.append(var)
        fields: list[tuple[int, int, int]] = []
        for var, value in zip(variables, values.values(), strict=True):
            try:
                fields.append((output_bit_offset(s, var), var.bit_length, var.encode(value)))
            except ProcessValueError as exc:
                raise ProcessValueError(f"{s}: {exc}") from None
        assigned = dict(zip((v.name for v in variables), values.values(), strict=True))
        self._check_device_rule(s, assigned)
        return fields

    def _check_device_rule(self, s: Slave, assigned: Mapping[str, object]) -> None:
        """What the device itself would refuse or disregard, refused here with the reason."""
        if s.device is None or s.layout is None:
            return
        outputs = [(v.name, v.index, v.subindex) for v in s.layout.outputs]
        if not workspace.is_laelaps_leg(s.device.type_name, outputs):
            return
        current = {k: float(v) for k, v in self.outputs(s).items() if isinstance(v, int | float)}
        numbers = {k: float(v) for k, v in assigned.items() if isinstance(v, int | float)}
        problem = workspace.leg_write_problem(s.device.type_name, outputs, current, numbers)
        if problem is not None:
            raise ProcessValueError(f"{s}: {problem}")

    def _refuse_axis_owned(self, s: Slave, var: ProcessVariable) -> None:
        """The engine's axis stage writes its drives' controlwords, modes and targets every
        cycle: a variable write there would be overwritten, so it is refused."""
        if self.layout is None or s.area is None:
            return
        if self._axis_owned is None:
            self._axis_owned = axis_mod.output_bits(self._axes, self.layout)
        owned = self._axis_owned
        byte = s.area.output_offset + var.bit_offset // 8
        if byte in owned:
            raise ProcessValueError(f"{s}: variable {var.name!r} belongs to axis {owned[byte]}; "
                                    f"command it with bus.axis({owned[byte]!r})")  # fmt: skip

    def _write_fields(self, fields: list[tuple[int, int, int]]) -> None:
        """Validated output fields (image bit offset, bit length, raw) to the engine when
        running, and to the mirror."""
        with self._lock:
            if self._running():
                self.engine.write_output_fields(fields)
            for bit_offset, bit_length, raw in fields:
                write_bits(self.mirror, bit_offset, bit_length, raw)

    def reset_slave(self, s: Slave) -> None:
        """Slave ``s``'s outputs back to their safe values in the engine's buffer (not a
        command: no watchdog is fed)."""
        area = s.area
        if not self._running() or area is None or not area.output_bytes:
            return
        begin, end = area.output_offset, area.output_offset + area.output_bytes
        with self._lock:
            self.engine.reset_outputs(begin, end - begin)
            self.mirror[begin:end] = self.safe[begin:end]

    def clear_panic(self) -> None:
        with self._lock:
            self.engine.clear_panic()
            self.mirror = bytearray(self.safe)

    # -- reads ----------------------------------------------------------------------------------
    def output_area(self, s: Slave) -> bytes:
        """The slave's outputs as commanded: the engine's buffer while running, else the
        mirror."""
        assert s.area is not None
        begin, end = s.area.output_offset, s.area.output_offset + s.area.output_bytes
        if self._running():
            return bytes(self.engine.outputs())[begin:end]
        return bytes(self.mirror[begin:end])

    def input_area(self, s: Slave) -> bytes:
        assert self.layout is not None
        area = s.area
        if area is None:
            return b""
        image = bytes(self.engine.read_inputs()) if self._running() else b""
        if len(image) == self.layout.image_len:
            return image[area.input_offset : area.input_offset + area.input_bytes]
        if len(image) == self.layout.input_bytes:
            offset = area.input_offset - self.layout.output_bytes
            return image[offset : offset + area.input_bytes]
        return bytes(area.input_bytes)

    def read(self, s: Slave, variable: str, stale_ok: bool) -> Value:
        var = self.variable(s, variable)
        assert s.layout is not None and s.area is not None
        if var.direction == "output":
            return s.layout.read(self.output_area(s), var)
        if not stale_ok:
            self.check_fresh(s)
        return s.layout.read(self.input_area(s), var)

    def inputs(self, s: Slave, stale_ok: bool) -> dict[str, Value]:
        if s.layout is None:
            return {}
        if not stale_ok:
            self.check_fresh(s)
        return s.layout.unpack(self.input_area(s), "input")

    def outputs(self, s: Slave) -> dict[str, Value]:
        if s.layout is None or s.area is None:
            return {}
        return s.layout.unpack(self.output_area(s), "output")

    def frames(self, s: Slave) -> tuple[int, ...]:
        if self.layout is None or s.area is None:
            return ()
        return self.layout.frames_of(s.name)

    def fresh(self, s: Slave) -> bool:
        frames = self.frames(s)
        if not self._running():
            return False
        if not frames:
            return True  # no process data: nothing to be stale
        mask = int(self.engine.stale_mask())
        return not any(mask >> k & 1 for k in frames)

    def age(self, s: Slave) -> float:
        frames = self.frames(s)
        if not self._running() or not frames:
            return float("inf")
        stats = self.engine.stats().get("frames") or []
        now = now_monotonic_ns()
        ages = []
        for k in frames:
            f = stats[k] if k < len(stats) else {}
            good = int(f.get("last_good_ns", 0))
            ages.append((now - good) / 1e9 if f.get("last_good_cycle") and good else float("inf"))
        return max(ages)

    def check_fresh(self, s: Slave) -> None:
        if not self._running():
            raise StaleInputs(f"slave '{s.name}': no inputs, the bus is not running")
        deadline = time.monotonic() + STALE_GRACE_S
        while not self.fresh(s):
            if time.monotonic() < deadline:
                time.sleep(0.001)
                continue
            age = self.age(s)
            since = "never came back whole" if age == float("inf") else f"{age * 1000:.0f} ms"
            raise StaleInputs(
                f"slave '{s.name}': inputs are stale (its frame's last whole reply: {since}); "
                "the bus or the slave is down"
            )

    def decode(self, image: bytes, s: Slave) -> dict[str, Value]:
        if s.layout is None or s.area is None:
            return {}
        a = s.area
        data = bytes(image[a.input_offset : a.input_offset + a.input_bytes])
        return s.layout.unpack(data, "input")
