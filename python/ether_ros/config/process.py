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

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass

from ether_ros._native.protocol import format_address, parse_address
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

    @property
    def key(self) -> str:
        """``0x7000:01``: the name that is always unique (the canonical object address)."""
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


class ProcessLayout:
    """The output and input variables of one slave for a given PDO assignment."""

    def __init__(self, outputs: Sequence[ProcessVariable], inputs: Sequence[ProcessVariable],
                 output_bits: int, input_bits: int, rx_pdos: Sequence[int],
                 tx_pdos: Sequence[int]) -> None:  # fmt: skip
        self.outputs: tuple[ProcessVariable, ...] = tuple(outputs)
        self.inputs: tuple[ProcessVariable, ...] = tuple(inputs)
        self.output_bits = output_bits
        self.input_bits = input_bits
        self.rx_pdos = tuple(rx_pdos)
        self.tx_pdos = tuple(tx_pdos)
        self._by_key: dict[tuple[int, int], ProcessVariable] = {}
        self._by_name: dict[str, list[ProcessVariable]] = {}
        for v in (*self.outputs, *self.inputs):
            self._by_key[(v.index, v.subindex)] = v
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
        rx_pdos: Iterable[int] | None = None,
        tx_pdos: Iterable[int] | None = None,
    ) -> ProcessLayout:
        """Layout of ``device`` with the given PDO assignment (default: the ESI's)."""
        rx = tuple(device.default_rx_pdos() if rx_pdos is None else rx_pdos)
        tx = tuple(device.default_tx_pdos() if tx_pdos is None else tx_pdos)
        outs, obits = _place(device, rx, "rx", "output")
        ins, ibits = _place(device, tx, "tx", "input")
        return cls(outs, ins, obits, ibits, rx, tx)

    def has(self, name: str) -> bool:
        try:
            return name in self._by_name or self._lookup_key(name) is not None
        except ProcessValueError:
            return False

    def variable(self, name: str) -> ProcessVariable:
        """A variable by entry name (``hip_angle``) or by object address (``0x7000:01``,
        ``7000:1``: hexadecimal, the grammar of ``ether_ros._native.protocol.parse_address``).

        Raises :class:`ProcessValueError` for unknown or ambiguous names."""
        found = self._by_name.get(name)
        if found is not None:
            if len(found) > 1:
                keys = ", ".join(v.key for v in found)
                raise ProcessValueError(f"variable name {name!r} is ambiguous; use one of {keys}")
            return found[0]
        by_key = self._lookup_key(name)
        if by_key is not None:
            return by_key
        raise ProcessValueError(f"no process variable {name!r}")

    def _lookup_key(self, name: str) -> ProcessVariable | None:
        try:
            address = parse_address(name)
        except ValueError as exc:
            raise ProcessValueError(str(exc)) from None
        return None if address is None else self._by_key.get(address)

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
            var = self.variable(name)
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


def _place(
    device: EsiDevice, pdos: Sequence[int], kind: str, direction: str
) -> tuple[list[ProcessVariable], int]:
    variables: list[ProcessVariable] = []
    bit = 0
    for index in pdos:
        pdo: Pdo | None = device.pdo(index)
        if pdo is None or pdo.direction != kind:
            what = "RxPDO" if kind == "rx" else "TxPDO"
            have = ", ".join(
                f"{p.index:#06x}" for p in (device.rx_pdos if kind == "rx" else device.tx_pdos)
            )
            raise ConfigError(
                f"{device.type_name} has no {what} {index:#06x} (it has: {have or 'none'})"
            )
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
                    )
                )
            bit += e.bit_length
    return variables, bit


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
