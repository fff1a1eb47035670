"""CoE data types (ETG.1000.6 codes) and the names ESI files use for them.

One table serves the ESI parser (type names → codes), the SII builder (codes in PDO entries),
the process-variable codec (bit length, signedness, range) and the simulator spec.
"""

from __future__ import annotations

import re
import struct
from dataclasses import dataclass


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
        if self.kind == "int":
            return -(1 << (self.bit_length - 1)), (1 << (self.bit_length - 1)) - 1
        if self.kind == "uint":
            return 0, (1 << self.bit_length) - 1
        if self.kind == "bool":
            return 0, 1
        return None


BOOL = DataType(0x0001, "bool", 1, "bool")
INT8 = DataType(0x0002, "int8", 8, "int")
INT16 = DataType(0x0003, "int16", 16, "int")
INT32 = DataType(0x0004, "int32", 32, "int")
UINT8 = DataType(0x0005, "uint8", 8, "uint")
UINT16 = DataType(0x0006, "uint16", 16, "uint")
UINT32 = DataType(0x0007, "uint32", 32, "uint")
REAL32 = DataType(0x0008, "real32", 32, "real")
STRING = DataType(0x0009, "string", 0, "string")
OCTET_STRING = DataType(0x000A, "octet_string", 0, "bytes")
INT24 = DataType(0x0010, "int24", 24, "int")
REAL64 = DataType(0x0011, "real64", 64, "real")
INT64 = DataType(0x0015, "int64", 64, "int")
UINT24 = DataType(0x0016, "uint24", 24, "uint")
UINT64 = DataType(0x001B, "uint64", 64, "uint")
UNICODE_STRING = DataType(0x000B, "unicode_string", 0, "bytes")
# BITARR8/16/32 (ETG.1000.6 0x2D..0x2F): bit arrays, handled as unsigned integers.
BITARR8 = DataType(0x002D, "bitarr8", 8, "uint")
BITARR16 = DataType(0x002E, "bitarr16", 16, "uint")
BITARR32 = DataType(0x002F, "bitarr32", 32, "uint")
# BIT1..BIT8 (ETG.1000.6 0x30..0x37): unsigned bit fields.
BITS = {n: DataType(0x002F + n, f"bit{n}", n, "uint") for n in range(1, 9)}

ALL_TYPES: tuple[DataType, ...] = (
    BOOL,
    INT8,
    INT16,
    INT32,
    UINT8,
    UINT16,
    UINT32,
    REAL32,
    STRING,
    OCTET_STRING,
    UNICODE_STRING,
    BITARR8,
    BITARR16,
    BITARR32,
    INT24,
    REAL64,
    INT64,
    UINT24,
    UINT64,
    *BITS.values(),
)
BY_CODE: dict[int, DataType] = {t.code: t for t in ALL_TYPES}
BY_NAME: dict[str, DataType] = {t.name: t for t in ALL_TYPES}

# Names used in ESI files (IEC 61131-3 and ETG.1000.6 spellings) → type.
_ESI_NAMES: dict[str, DataType] = {
    "BOOL": BOOL,
    "BOOLEAN": BOOL,
    "BIT": BITS[1],
    "SINT": INT8,
    "INTEGER8": INT8,
    "INT": INT16,
    "INTEGER16": INT16,
    "DINT": INT32,
    "INTEGER32": INT32,
    "INT24": INT24,
    "INTEGER24": INT24,
    "LINT": INT64,
    "INTEGER64": INT64,
    "USINT": UINT8,
    "BYTE": UINT8,
    "UNSIGNED8": UINT8,
    "UINT": UINT16,
    "WORD": UINT16,
    "UNSIGNED16": UINT16,
    "UINT24": UINT24,
    "UNSIGNED24": UINT24,
    "UDINT": UINT32,
    "DWORD": UINT32,
    "UNSIGNED32": UINT32,
    "ULINT": UINT64,
    "LWORD": UINT64,
    "UNSIGNED64": UINT64,
    "REAL": REAL32,
    "REAL32": REAL32,
    "FLOAT": REAL32,
    "LREAL": REAL64,
    "REAL64": REAL64,
    "DOUBLE": REAL64,
    "STRING": STRING,
    "VISIBLE_STRING": STRING,
    "OCTET_STRING": OCTET_STRING,
    "UNICODE_STRING": UNICODE_STRING,
    "BITARR8": BITARR8,
    "BITARR16": BITARR16,
    "BITARR32": BITARR32,
    # Aliases vendors write (C-style widths, e.g. SMC's ``UINT8``).
    "UINT8": UINT8,
    "UINT16": UINT16,
    "UINT32": UINT32,
    "UINT64": UINT64,
    "INT8": INT8,
    "INT16": INT16,
    "INT32": INT32,
    "INT64": INT64,
    "FLOAT32": REAL32,
    "FLOAT64": REAL64,
}
_SIZED = re.compile(
    r"^(STRING|VISIBLE_STRING|OCTET_STRING|UNICODE_STRING|ARRAY OF BYTE)\s*\(\s*(\d+)\s*\)$"
)
# "ARRAY [0..511] OF BYTE", the spelling several vendors use for byte arrays.
_BYTE_ARRAY = re.compile(r"^ARRAY\s*\[\s*\d+\s*\.\.\s*\d+\s*\]\s*OF\s*(BYTE|USINT|UINT8)$")
_BITN = re.compile(r"^BIT([1-8])$")


def esi_type(name: str) -> DataType | None:
    """The basic type an ESI type name denotes (``USINT``, ``BIT3``, ``STRING(20)``), or None
    when it is not a basic type (e.g. a record type such as ``DT7000``)."""
    key = name.strip().upper()
    if key in _ESI_NAMES:
        return _ESI_NAMES[key]
    if m := _BITN.match(key):
        return BITS[int(m.group(1))]
    if m := _SIZED.match(key):
        kind = m.group(1)
        if kind in ("STRING", "VISIBLE_STRING"):
            return STRING
        return UNICODE_STRING if kind == "UNICODE_STRING" else OCTET_STRING
    if _BYTE_ARRAY.match(key):
        return OCTET_STRING
    return None


def config_type(name: str) -> DataType | None:
    """The type a bus config's ``type:`` names: canonical names (``uint16``) or ESI names."""
    return BY_NAME.get(name.strip().lower()) or esi_type(name)


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
    lo, hi = int_range(dtype, bit_length)
    if not lo <= value <= hi:
        raise ValueError(f"{value} is out of range for {dtype.name} [{lo}, {hi}]")
    return value & ((1 << bit_length) - 1)


def from_raw(dtype: DataType, raw: int, bit_length: int) -> int | bool:
    """The value of an unsigned bit pattern read from the wire."""
    if dtype.kind == "bool":
        return bool(raw & 1)
    if dtype.kind == "int" and raw & (1 << (bit_length - 1)):
        return raw - (1 << bit_length)
    return raw


def int_range(dtype: DataType, bit_length: int) -> tuple[int, int]:
    if dtype.kind == "int":
        return -(1 << (bit_length - 1)), (1 << (bit_length - 1)) - 1
    if dtype.kind == "bool":
        return 0, 1
    return 0, (1 << bit_length) - 1


def decode_value(dtype: DataType, data: bytes, bit_length: int) -> object:
    """Inverse of :func:`encode_value`."""
    if dtype.kind in ("bool", "int", "uint"):
        raw = int.from_bytes(data, "little") & ((1 << bit_length) - 1)
        return from_raw(dtype, raw, bit_length)
    if dtype.kind == "real":
        return float(struct.unpack("<f" if bit_length == 32 else "<d", data)[0])
    if dtype.kind == "string":
        return data.split(b"\0", 1)[0].decode("utf-8", "replace")
    return bytes(data)
