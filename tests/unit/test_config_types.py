"""How values print (``config.types.format_number``): whole numbers and counters never in
exponent notation, reals to the digits their type has (issue 28 item 4, issue 30 item 6)."""

from __future__ import annotations

import math

import pytest

from ether_ros.config.types import format_number


@pytest.mark.parametrize(
    ("value", "type_name", "text"),
    [
        (79036400.0, "int32", "79036400"),  # printed as 7.90364e+07 before
        (-2147483648.0, "INT32", "-2147483648"),
        (18446744073709551615.0, "uint64", "18446744073709551616"),  # as the float holds it
        (1.0, "bool", "1"),
        (1234567.0, None, "1234567"),  # a counter
        (0.1, "real64", "0.1"),
        (0.10000000149011612, "real32", "0.1"),  # a REAL32's 0.1 after float64
        (1e-9, "real64", "1e-09"),
        (3.0, "real64", "3.0"),
        (12.5, None, "12.5"),
        (math.inf, None, "inf"),
        (math.nan, "int32", "nan"),
    ],
)
def test_values_print_as_their_type(value: float, type_name: str | None, text: str) -> None:
    assert format_number(value, type_name) == text
