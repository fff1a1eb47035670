"""Values of typed process variables and SDO objects: turning user text (or a ROS float) into a
checked value.

Used on both sides of ROS: the console refuses a bad value before anything is sent, and the node
checks again every write it receives (any ROS client may publish), so an invalid write never
reaches the process image. Types, ranges and the check itself are the protocol crate's
(``ether_ros._native.protocol``: the native command path checks with the same function).
"""

from __future__ import annotations

import functools
import math

from ether_ros._native import protocol
from ether_ros.config import types as dt
from ether_ros.errors import EtherRosError
from ether_ros.ros.layout import VariableSpec


class InvalidValue(EtherRosError):
    """A value that does not fit its variable (names the variable, type and range)."""


@functools.lru_cache(maxsize=256)
def data_type(type_name: str) -> dt.DataType:
    """The type a name denotes (``int16``, ``INT``, ``UINT``, ``bool``, ``real32`` ...)."""
    t = dt.config_type(type_name)
    if t is None or t.kind in ("string", "bytes"):
        raise InvalidValue(f"unsupported data type '{type_name}'")
    return t


def type_range(type_name: str, bit_length: int = 0) -> tuple[float, float]:
    """(minimum, maximum) of a numeric type."""
    t = data_type(type_name)
    lo, hi = protocol.value_range(
        t.kind, t.bit_length if t.kind == "real" else bit_length or t.bit_length
    )
    return float(lo), float(hi)


def is_integer_type(type_name: str) -> bool:
    return data_type(type_name).kind in ("int", "uint", "bool")


def is_bool_type(type_name: str) -> bool:
    return data_type(type_name).kind == "bool"


_TRUE = {"true", "on", "yes"}
_FALSE = {"false", "off", "no"}


def parse_text(text: str, var: VariableSpec) -> float:
    """User text for ``var`` -> its value as a float (exact for integers up to 2^53), checked
    against the type and the variable's range. Accepts decimal, 0x/0b/0o integers, true/false
    for booleans and decimals for reals."""
    raw = text.strip()
    if not raw:
        raise InvalidValue(f"no value given for {var.name}")
    lowered = raw.lower()
    value: float
    if is_bool_type(var.type) and lowered in _TRUE | _FALSE:
        value = 1.0 if lowered in _TRUE else 0.0
    elif is_integer_type(var.type):
        value = _integer(raw, text, var)
    else:
        try:
            value = float(raw)
        except ValueError:
            raise InvalidValue(f"{var.name} is {var.type}: '{text}' is not a number") from None
    return check_value(value, var)


def _integer(raw: str, text: str, var: VariableSpec) -> float:
    try:
        return float(int(raw.replace("_", ""), 0))
    except ValueError:
        pass
    try:
        as_float = float(raw)
    except ValueError:
        as_float = math.nan
    if not as_float.is_integer():
        raise InvalidValue(f"{var.name} is {var.type}: '{text}' is not an integer")
    return as_float


def check_value(value: float, var: VariableSpec) -> float:
    """``value`` if it is valid for ``var``, else :class:`InvalidValue` saying why."""
    try:
        protocol.check_value(data_type(var.type).kind, value, var.minimum, var.maximum)
    except protocol.ValueCheckError as exc:
        if exc.reason == "not_finite":
            raise InvalidValue(f"{var.name} ({var.type}): {value} is not a finite number") from None
        if exc.reason == "not_integer":
            raise InvalidValue(f"{var.name} is {var.type}: {value:g} is not an integer") from None
        raise InvalidValue(
            f"{var.name} ({var.type}): {format_value(value, var)} is outside "
            f"{format_value(var.minimum, var)}..{format_value(var.maximum, var)}"
        ) from None
    return float(value)


def format_value(value: float, var: VariableSpec) -> str:
    """A variable's value as its type prints (``config.types.format_number``)."""
    return dt.format_number(value, var.type)


def to_python(value: float, type_name: str) -> bool | int | float:
    """The Python value the Bus API takes for a variable of ``type_name``."""
    t = data_type(type_name)
    if t.kind == "bool":
        return bool(value)
    if t.kind in ("int", "uint"):
        return int(value)
    return float(value)


def to_float(value: object) -> float:
    """A decoded process value as the float64 published in ``SlaveValues``."""
    if isinstance(value, bool | int | float):
        return float(value)
    raise InvalidValue(f"value {value!r} is not numeric")
