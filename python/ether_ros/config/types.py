"""CoE data types (ETG.1000.6 codes) and the names ESI files use for them, as Python sees them.

The table itself (codes, bit sizes, how values encode, ESI spellings) and the range check of
integer values are the protocol crate's (``ether_ros._native.protocol``); this module gives
them Python types. One table serves the ESI parser (type names → codes), the SII builder (codes
in PDO entries), the process-variable codec (bit length, signedness, range) and the simulator
spec.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

from ether_ros._native import protocol
from ether_ros._native.protocol import dtype


@dataclass(frozen=True)
class DataType:
    """A basic CoE data type."""

    code: int  # ETG.1000.6 data type index (0x0001 BOOL ... 0x001B UINT64)
    name: str  # canonical short name used in the bus config (`type:`) and messages
    bit_length: int  # 0 for variable-length types (strings, octet strings)
    kind: str  # 'bool' | 'int' | 'uint' | 'real' | 'string' | 'bytes'

    @property
    def signed(self) -> bool:
        return self.kind == "int"

    def range(self) -> tuple[int, int] | None:
        """Inclusive value range of an integer type, None for the others."""
        if self.kind in ("int", "uint", "bool"):
            return int_range(self, self.bit_length)
        return None


ALL_TYPES: tuple[DataType, ...] = tuple(DataType(*t) for t in protocol.data_types())
BY_CODE: dict[int, DataType] = {t.code: t for t in ALL_TYPES}
BY_NAME: dict[str, DataType] = {t.name: t for t in ALL_TYPES}

BOOL = BY_CODE[dtype.BOOL]
INT8 = BY_CODE[dtype.INT8]
INT16 = BY_CODE[dtype.INT16]
INT32 = BY_CODE[dtype.INT32]
UINT8 = BY_CODE[dtype.UINT8]
UINT16 = BY_CODE[dtype.UINT16]
UINT32 = BY_CODE[dtype.UINT32]
REAL32 = BY_CODE[dtype.REAL32]
STRING = BY_CODE[dtype.VISIBLE_STRING]
OCTET_STRING = BY_CODE[dtype.OCTET_STRING]
UNICODE_STRING = BY_CODE[dtype.UNICODE_STRING]
INT24 = BY_CODE[dtype.INT24]
REAL64 = BY_CODE[dtype.REAL64]
INT64 = BY_CODE[dtype.INT64]
UINT24 = BY_CODE[dtype.UINT24]
UINT64 = BY_CODE[dtype.UINT64]
BITARR8 = BY_CODE[dtype.BITARR8]
BITARR16 = BY_CODE[dtype.BITARR16]
BITARR32 = BY_CODE[dtype.BITARR32]
# BIT1..BIT8: unsigned bit fields.
BITS = {n: BY_CODE[dtype.BIT1 + n - 1] for n in range(1, 9)}


def esi_type(name: str) -> DataType | None:
    """The basic type an ESI type name denotes (``USINT``, ``BIT3``, ``STRING(20)``), or None
    when it is not a basic type (e.g. a record type such as ``DT7000``)."""
    code = protocol.esi_type(name)
    return None if code is None else BY_CODE[code]


def config_type(name: str) -> DataType | None:
    """The type a bus config's ``type:`` names: canonical names (``uint16``) or ESI names."""
    code = protocol.config_type(name)
    return None if code is None else BY_CODE[code]


def esi_name(dtype_: DataType) -> str:
    """The ESI name a type is usually written with (``UINT`` for uint16)."""
    return protocol.esi_type_name(dtype_.code) or dtype_.name.upper()


def encode_value(dtype: DataType, value: object, bit_length: int) -> bytes:
    """Little-endian bytes (``ceil(bit_length/8)`` long) of ``value`` as ``dtype``.

    Raises ``ValueError`` saying the type and its range when the value does not fit.
    """
    nbytes = (bit_length + 7) // 8
    if dtype.kind in ("bool", "int", "uint"):
        raw = to_raw(dtype, value, bit_length)
        return raw.to_bytes(nbytes, "little")
    if dtype.kind == "real":
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise ValueError(f"{dtype.name} needs a number, got {value!r}")
        return struct.pack("<f" if bit_length == 32 else "<d", float(value))
    if dtype.kind == "string":
        if not isinstance(value, str):
            raise ValueError(f"{dtype.name} needs text, got {value!r}")
        data = value.encode("utf-8")
    else:
        if isinstance(value, str):
            try:
                data = bytes.fromhex(value)
            except ValueError as exc:
                raise ValueError(f"{dtype.name} needs hex bytes, got {value!r}") from exc
        elif isinstance(value, bytes | bytearray):
            data = bytes(value)
        else:
            raise ValueError(f"{dtype.name} needs bytes, got {value!r}")
    if nbytes and len(data) > nbytes:
        raise ValueError(f"{dtype.name} holds {nbytes} bytes, got {len(data)}")
    return data.ljust(nbytes, b"\0") if nbytes else data


def to_raw(dtype: DataType, value: object, bit_length: int) -> int:
    """The unsigned bit pattern (``bit_length`` bits) of an integer or bool value."""
    if dtype.kind == "bool":
        if isinstance(value, bool):
            return int(value)
        if isinstance(value, int) and value in (0, 1):
            return value
        raise ValueError(f"bool needs true/false or 0/1, got {value!r}")
    if isinstance(value, bool) or not isinstance(value, int):
        if isinstance(value, float) and value.is_integer():
            value = int(value)
        else:
            raise ValueError(f"{dtype.name} needs an integer, got {value!r}")
    try:
        return protocol.encode_int(dtype.kind, bit_length, value)
    except protocol.ValueCheckError as exc:
        if exc.reason != "out_of_range":
            raise ValueError(f"{dtype.name} cannot have {bit_length} bits") from None
        lo, hi = int_range(dtype, bit_length)
        raise ValueError(f"{value} is out of range for {dtype.name} [{lo}, {hi}]") from None


def from_raw(dtype: DataType, raw: int, bit_length: int) -> int | bool:
    """The value of an unsigned bit pattern read from the wire."""
    if dtype.kind == "bool":
        return bool(raw & 1)
    return protocol.decode_int(dtype.kind, bit_length, raw)


def int_range(dtype: DataType, bit_length: int) -> tuple[int, int]:
    """Inclusive range of an integer (or bool) type at ``bit_length`` bits."""
    kind = dtype.kind if dtype.kind in ("int", "bool") else "uint"
    lo, hi = protocol.value_range(kind, bit_length)
    return int(lo), int(hi)


def decode_value(dtype: DataType, data: bytes, bit_length: int) -> object:
    """Inverse of :func:`encode_value`."""
    if dtype.kind in ("bool", "int", "uint"):
        raw = int.from_bytes(data, "little") & ((1 << bit_length) - 1)
        return from_raw(dtype, raw, bit_length)  # sign extension: the protocol crate's
    if dtype.kind == "real":
        return float(struct.unpack("<f" if bit_length == 32 else "<d", data)[0])
    if dtype.kind == "string":
        return data.split(b"\0", 1)[0].decode("utf-8", "replace")
    return bytes(data)


def format_number(value: float, type_name: str | None = None) -> str:
    """A value as a person reads it, never in exponent notation when it is a whole number:
    an integer, a boolean and a counter (``type_name`` None: a count sent as a float) print as
    integers; REAL32 to the 7 significant digits it has; REAL64 and anything else to the
    shortest text that reads back as the same float."""
    if value != value or value in (float("inf"), float("-inf")):
        return str(value)
    t = config_type(type_name) if type_name is not None else None
    whole = float(value).is_integer() and abs(value) <= 2**64
    if whole and (t is None or t.kind in ("bool", "int", "uint")):
        return str(int(value))
    if t is not None and t.code == dtype.REAL32:
        return f"{value:.7g}"
    return repr(float(value))
