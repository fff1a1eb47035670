"""Process variables of one slave: where each PDO entry sits in the slave's output and input
areas, and the codec between Python values and those bits.

The output area of a slave is its assigned RxPDOs' entries one after the other, bit-packed, in
assignment order; the input area is the same for the TxPDOs. That is what the slave's
SyncManagers hold and what the master's FMMUs map into the frame, so a bit offset here is the bit
offset inside the slave's part of the process image. Padding entries (index 0) take their bits
but have no variable.

Example::

    layout = ProcessLayout.for_device(esi_device)          # default PDO assignment
    out = bytearray(layout.output_bytes)
    layout.write(out, "State_Machine", 1)
    layout.write(out, "0x7030:03", 500)                    # a_ellipse100 by index:subindex
    angle = layout.read(inputs, "hip_angle")
"""

from __future__ import annotations

import threading
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, replace

from ether_ros._native.protocol import format_address, format_pdo_address, parse_pdo_address
from ether_ros.config import types as dt
from ether_ros.config.esi import EsiDevice, Pdo
from ether_ros.errors import ConfigError, EtherRosError

Value = int | float | bool


class ProcessValueError(EtherRosError, ValueError):
    """A value does not fit a process variable; names the variable, its type and range."""


@dataclass(frozen=True)
class ProcessVariable:
    name: str
    index: int
    subindex: int
    direction: str  # 'output' (RxPDO, master → slave) | 'input' (TxPDO, slave → master)
    bit_offset: int  # within the slave's output or input area
    bit_length: int
    data_type: int  # ETG.1000.6 code
    pdo: int  # index of the PDO the entry is mapped in
    # The entry is mapped more than once in the layout (e.g. one object in an RxPDO and a
    # TxPDO): its key names the PDO too.
    qualified: bool = False
    sm: int = 0  # the SyncManager that carries it

    @property
    def key(self) -> str:
        """``0x7000:01``, or ``0x1600/0x7000:01`` when the entry is mapped more than once: the
        name that is always unique (the canonical object address, with its PDO when needed)."""
        if self.qualified:
            return format_pdo_address(self.pdo, self.index, self.subindex)
        return format_address(self.index, self.subindex)

    @property
    def dtype(self) -> dt.DataType:
        return dt.BY_CODE.get(self.data_type) or dt.OCTET_STRING

    @property
    def byte_offset(self) -> int:
        return self.bit_offset // 8

    def range(self) -> tuple[int, int] | None:
        t = self.dtype
        if t.kind in ("int", "uint", "bool"):
            return dt.int_range(t, self.bit_length)
        return None

    def encode(self, value: object) -> int:
        """The raw bit pattern (``bit_length`` bits, unsigned) of ``value``."""
        t = self.dtype
        try:
            if t.kind == "real":
                if isinstance(value, bool) or not isinstance(value, int | float):
                    raise ValueError(f"needs a number, got {value!r}")
                return int.from_bytes(dt.encode_value(t, value, self.bit_length), "little")
            if t.kind in ("string", "bytes"):
                raise ValueError("string/octet-string variables are not supported in PDOs")
            return dt.to_raw(t, value, self.bit_length)
        except ValueError as exc:
            raise ProcessValueError(f"variable {self.name} ({self.key}, {t.name}): {exc}") from None

    def decode(self, raw: int) -> Value:
        t = self.dtype
        if t.kind == "real":
            v = dt.decode_value(t, raw.to_bytes(self.bit_length // 8, "little"), self.bit_length)
            assert isinstance(v, float)
            return v
        return dt.from_raw(t, raw, self.bit_length)


@dataclass(frozen=True)
class SmSegment:
    """The part of a slave's output or input area one SyncManager carries: it starts on a byte
    boundary and holds the SM's assigned PDOs bit-packed in assignment order."""

    sm: int  # SyncManager number (the device's <Sm> order)
    direction: str  # 'output' | 'input'
    byte_offset: int  # in the slave's output or input area
    byte_length: int
    pdos: tuple[int, ...]


# Layouts made, by (device, rx assignment, tx assignment): see ProcessLayout.for_device.
_layouts: dict[tuple[int, object, object], tuple[EsiDevice, ProcessLayout]] = {}
_layouts_lock = threading.Lock()


class ProcessLayout:
    """The output and input variables of one slave for a given PDO assignment."""

    def __init__(self, outputs: Sequence[ProcessVariable], inputs: Sequence[ProcessVariable],
                 output_bits: int, input_bits: int, rx_pdos: Sequence[int],
                 tx_pdos: Sequence[int],
                 segments: Sequence[SmSegment] = ()) -> None:  # fmt: skip
        self.output_bits = output_bits
        self.input_bits = input_bits
        self.rx_pdos = tuple(rx_pdos)
        self.tx_pdos = tuple(tx_pdos)
        self.segments: tuple[SmSegment, ...] = tuple(segments)
        # An entry mapped more than once gets a key that names its PDO too.
        plain: dict[tuple[int, int], int] = {}
        for v in (*outputs, *inputs):
            plain[(v.index, v.subindex)] = plain.get((v.index, v.subindex), 0) + 1
        qualify = {k for k, n in plain.items() if n > 1}
        self.outputs: tuple[ProcessVariable, ...] = tuple(_qualified(v, qualify) for v in outputs)
        self.inputs: tuple[ProcessVariable, ...] = tuple(_qualified(v, qualify) for v in inputs)
        self._by_key: dict[tuple[int | None, int, int], ProcessVariable] = {}
        self._by_address: dict[tuple[int, int], list[ProcessVariable]] = {}
        self._by_name: dict[str, list[ProcessVariable]] = {}
        for v in (*self.outputs, *self.inputs):
            self._by_key.setdefault((v.pdo if v.qualified else None, v.index, v.subindex), v)
            self._by_address.setdefault((v.index, v.subindex), []).append(v)
            self._by_name.setdefault(v.name, []).append(v)

    @property
    def output_bytes(self) -> int:
        return (self.output_bits + 7) // 8

    @property
    def input_bytes(self) -> int:
        return (self.input_bits + 7) // 8

    @property
    def variables(self) -> tuple[ProcessVariable, ...]:
        return (*self.outputs, *self.inputs)

    @classmethod
    def for_device(
        cls,
        device: EsiDevice,
        rx_pdos: Iterable[int | Pdo] | None = None,
        tx_pdos: Iterable[int | Pdo] | None = None,
    ) -> ProcessLayout:
        """Layout of ``device`` with the given PDO assignment (default: the ESI's). PDOs are
        given by index or as :class:`Pdo` objects (an ESI may give two PDOs one index).

        A layout is never changed once made, so the slaves of one device type with the same
        assignment share one: a bus of a thousand identical terminals lays it out once."""
        rx_key = None if rx_pdos is None else tuple(rx_pdos)
        tx_key = None if tx_pdos is None else tuple(tx_pdos)
        key = (id(device), rx_key, tx_key)
        with _layouts_lock:
            hit = _layouts.get(key)
        if hit is not None and hit[0] is device:
            return hit[1]
        layout = cls._for_device(device, rx_key, tx_key)
        with _layouts_lock:
            if len(_layouts) > 1024:
                _layouts.clear()
            _layouts[key] = (device, layout)  # the device kept: its id is not reused meanwhile
        return layout

    @classmethod
    def _for_device(
        cls,
        device: EsiDevice,
        rx_pdos: Iterable[int | Pdo] | None,
        tx_pdos: Iterable[int | Pdo] | None,
    ) -> ProcessLayout:
        rx = device.default_rx() if rx_pdos is None else _resolve(device, rx_pdos, "rx")
        tx = device.default_tx() if tx_pdos is None else _resolve(device, tx_pdos, "tx")
        outs, obits, oseg = _place(device, rx, "rx", "output")
        ins, ibits, iseg = _place(device, tx, "tx", "input")
        return cls(
            outs, ins, obits, ibits, [p.index for p in rx], [p.index for p in tx], [*oseg, *iseg]
        )

    def has(self, name: str) -> bool:
        try:
            return name in self._by_name or self._lookup_key(name) is not None
        except ProcessValueError:
            return False

    def variable(self, name: str, direction: str | None = None) -> ProcessVariable:
        """A variable by entry name (``hip_angle``) or by object address (``0x7000:01``,
        ``7000:1``: hexadecimal, the grammar of ``ether_ros._native.protocol.parse_address``;
        ``0x1600/0x7000:01`` for an entry mapped more than once); ``direction`` ('output' or
        'input') narrows a name or address used in both directions.

        Raises :class:`ProcessValueError` for unknown or ambiguous names."""
        found = self._by_name.get(name)
        if found is not None:
            if direction is not None and len(found) > 1:
                narrowed = [v for v in found if v.direction == direction]
                found = narrowed or found
            if len(found) > 1:
                keys = ", ".join(v.key for v in found)
                raise ProcessValueError(f"variable name {name!r} is ambiguous; use one of {keys}")
            return found[0]
        by_key = self._lookup_key(name, direction)
        if by_key is not None:
            return by_key
        raise ProcessValueError(f"no process variable {name!r}")

    def _lookup_key(self, name: str, direction: str | None = None) -> ProcessVariable | None:
        try:
            address = parse_pdo_address(name)
        except ValueError as exc:
            raise ProcessValueError(str(exc)) from None
        if address is None:
            return None
        pdo, index, subindex = address
        if pdo is not None:
            return self._by_key.get((pdo, index, subindex))
        found = self._by_address.get((index, subindex), [])
        if direction is not None and len(found) > 1:
            found = [v for v in found if v.direction == direction] or found
        if len(found) > 1:
            keys = ", ".join(v.key for v in found)
            raise ProcessValueError(f"{name!r} is mapped more than once; use one of {keys}")
        return found[0] if found else None

    # -- codec on area buffers ---------------------------------------------------------------

    def write(self, area: bytearray, name: str | ProcessVariable, value: object) -> None:
        """Encode ``value`` into ``area`` (the slave's output or input area)."""
        var = name if isinstance(name, ProcessVariable) else self.variable(name)
        write_bits(area, var.bit_offset, var.bit_length, var.encode(value))

    def read(self, area: bytes | bytearray | memoryview, name: str | ProcessVariable) -> Value:
        var = name if isinstance(name, ProcessVariable) else self.variable(name)
        return var.decode(read_bits(area, var.bit_offset, var.bit_length))

    def pack_outputs(self, values: Mapping[str, object], base: bytes | None = None) -> bytearray:
        """An output area with ``values`` (by name) written over ``base`` (default zeros)."""
        area = bytearray(base if base is not None else bytes(self.output_bytes))
        if len(area) != self.output_bytes:
            raise ProcessValueError(
                f"output area is {self.output_bytes} bytes, base has {len(area)}"
            )
        for name, value in values.items():
            var = self.variable(name, "output")
            if var.direction != "output":
                raise ProcessValueError(f"variable {name!r} is an input, not an output")
            self.write(area, var, value)
        return area

    def unpack(
        self, area: bytes | bytearray | memoryview, direction: str = "input"
    ) -> dict[str, Value]:
        """All variables of one area by name (``key`` for names used twice)."""
        variables = self.inputs if direction == "input" else self.outputs
        out: dict[str, Value] = {}
        for v in variables:
            name = v.name if len(self._by_name[v.name]) == 1 else v.key
            out[name] = self.read(area, v)
        return out


def _qualified(v: ProcessVariable, qualify: set[tuple[int, int]]) -> ProcessVariable:
    return replace(v, qualified=True) if (v.index, v.subindex) in qualify else v


def _resolve(device: EsiDevice, pdos: Iterable[int | Pdo], kind: str) -> tuple[Pdo, ...]:
    out: list[Pdo] = []
    for item in pdos:
        if isinstance(item, Pdo):
            out.append(item)
            continue
        pdo = device.pdo(item, kind)
        if pdo is None:
            what = "RxPDO" if kind == "rx" else "TxPDO"
            have = ", ".join(
                f"{p.index:#06x}" for p in (device.rx_pdos if kind == "rx" else device.tx_pdos)
            )
            raise ConfigError(
                f"{device.type_name} has no {what} {item:#06x} (it has: {have or 'none'})"
            )
        out.append(pdo)
    return tuple(out)


def pdo_sync_manager(device: EsiDevice, pdo: Pdo) -> int:
    """The SyncManager a PDO goes into: its ``Sm`` when that SM carries its direction, else
    the device's first real SM of the direction (where configurable PDOs go)."""
    role = "Outputs" if pdo.direction == "rx" else "Inputs"
    if pdo.sm is not None:
        sm = device.sm_number(pdo.sm)
        if sm is not None and sm.role == role:
            return pdo.sm
    main = device.sm(role)
    if main is None:
        what = "outputs" if pdo.direction == "rx" else "inputs"
        raise ConfigError(
            f"{device.type_name}: PDO {pdo.index:#06x} has no SyncManager (the device has no"
            f" SyncManager for {what})"
        )
    return main.number


def _place(
    device: EsiDevice, pdos: Sequence[Pdo], kind: str, direction: str
) -> tuple[list[ProcessVariable], int, list[SmSegment]]:
    """The variables of ``pdos`` and the area's SM segments: the PDOs grouped by their
    SyncManager (SM number order, assignment order within one SM), each SM from a byte
    boundary."""
    by_sm: dict[int, list[Pdo]] = {}
    for pdo in pdos:
        if pdo.direction != kind:
            what = "RxPDO" if kind == "rx" else "TxPDO"
            raise ConfigError(f"{device.type_name}: PDO {pdo.index:#06x} is not an {what}")
        sm = pdo_sync_manager(device, pdo) if device.sync_managers else 0
        by_sm.setdefault(sm, []).append(pdo)
    variables: list[ProcessVariable] = []
    segments: list[SmSegment] = []
    bit = 0
    for sm in sorted(by_sm):
        bit = (bit + 7) // 8 * 8
        start = bit
        for pdo in by_sm[sm]:
            for e in pdo.entries:
                if not e.is_padding:
                    variables.append(
                        ProcessVariable(
                            name=e.name,
                            index=e.index,
                            subindex=e.subindex,
                            direction=direction,
                            bit_offset=bit,
                            bit_length=e.bit_length,
                            data_type=e.data_type,
                            pdo=pdo.index,
                            sm=sm,
                        )
                    )
                bit += e.bit_length
        segments.append(
            SmSegment(
                sm,
                direction,
                start // 8,
                (bit - start + 7) // 8,
                tuple(p.index for p in by_sm[sm]),
            )
        )
    return variables, bit, segments


def read_bits(area: bytes | bytearray | memoryview, bit_offset: int, bit_length: int) -> int:
    """Little-endian bit field of ``area`` (EtherCAT bit order: bit 0 is the LSB of byte 0)."""
    first = bit_offset // 8
    last = (bit_offset + bit_length + 7) // 8
    if last > len(area):
        raise ProcessValueError(
            f"area of {len(area)} bytes is too short for bits {bit_offset}+{bit_length}"
        )
    chunk = int.from_bytes(bytes(area[first:last]), "little")
    return (chunk >> (bit_offset % 8)) & ((1 << bit_length) - 1)


def write_bits(area: bytearray, bit_offset: int, bit_length: int, raw: int) -> None:
    first = bit_offset // 8
    last = (bit_offset + bit_length + 7) // 8
    if last > len(area):
        raise ProcessValueError(
            f"area of {len(area)} bytes is too short for bits {bit_offset}+{bit_length}"
        )
    shift = bit_offset % 8
    mask = ((1 << bit_length) - 1) << shift
    chunk = int.from_bytes(area[first:last], "little")
    chunk = (chunk & ~mask) | ((raw << shift) & mask)
    area[first:last] = chunk.to_bytes(last - first, "little")
