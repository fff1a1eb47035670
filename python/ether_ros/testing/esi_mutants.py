"""Hostile and broken ESI files made from good ones: a seeded mutation generator for the tests
(``tests/unit/test_esi_hostile.py``) and for longer runs by hand.

Each mutant changes one thing a broken tool or a hostile author could: a number replaced by an
absurd one (huge, negative, in another script's digits, with separators, not a number), an
element deleted or repeated many times, text or bytes cut, bad UTF-8, an element nested deep.
The same seed gives the same mutants.
"""

from __future__ import annotations

import random
import re
from collections.abc import Iterator

#: Values a number field may be given by a hostile file.
HOSTILE_NUMBERS = (
    "", " ", "-1", "-2147483649", "#x", "0x", "#xG1", "#x-1", "1_000", "1e3", "1.5", "+",
    "١٢٣", "٣", "NaN", "inf", "true", "9" * 5000, "#x" + "F" * 40, "18446744073709551616",
    "4294967296", "65536", "256", "#x80000000", "-#x10", "0x0x10", "#x0x10", "12abc",
    "\u00a0 7", "7\u200b",
)  # fmt: skip
_NUMBER_TEXT = re.compile(rb">(#x[0-9A-Fa-f]+|0x[0-9A-Fa-f]+|-?[0-9]+)<")
_ATTR_NUMBER = re.compile(rb'="(#x[0-9A-Fa-f]+|0x[0-9A-Fa-f]+|-?[0-9]+)"')
_ELEMENT = re.compile(
    rb"<(Entry|RxPdo|TxPdo|Object|SubItem|DataType|Sm|Device|Index|BitLen|SubIndex|Type|Name|"
    rb"DefaultData|DefaultValue|ArrayInfo|Elements|BitSize|Fmmu|Dc|OpMode|Mailbox|CoE|InitCmd|"
    rb"Eeprom)\b"
)


def _replace_span(data: bytes, span: tuple[int, int], new: bytes) -> bytes:
    return data[: span[0]] + new + data[span[1] :]


def _element_span(data: bytes, start: int) -> tuple[int, int] | None:
    """The span of the element starting at ``start`` (to its matching end tag, one level)."""
    m = re.match(rb"<([A-Za-z]+)", data[start:])
    if m is None:
        return None
    name = m.group(1)
    end = data.find(b"</" + name + b">", start)
    if end < 0:
        close = data.find(b"/>", start)
        return (start, close + 2) if close >= 0 else None
    return start, end + len(name) + 3


def mutants(text: bytes, seed: int, count: int) -> Iterator[tuple[str, bytes]]:
    """``count`` mutants of the ESI ``text``: (what was done, the mutated bytes)."""
    rng = random.Random(seed)
    numbers = [m.span(1) for m in _NUMBER_TEXT.finditer(text)]
    attrs = [m.span(1) for m in _ATTR_NUMBER.finditer(text)]
    elements = [m.start() for m in _ELEMENT.finditer(text)]
    kinds = ("number", "attribute", "delete", "repeat", "truncate", "utf8", "nest", "swap")
    for n in range(count):
        kind = kinds[n % len(kinds)]
        if kind == "number" and numbers:
            span = rng.choice(numbers)
            value = rng.choice(HOSTILE_NUMBERS)
            yield (
                f"number {text[span[0] : span[1]]!r} -> {value[:20]!r}",
                _replace_span(text, span, value.encode()),
            )
        elif kind == "attribute" and attrs:
            span = rng.choice(attrs)
            value = rng.choice(HOSTILE_NUMBERS).replace('"', "")
            yield (
                f"attribute {text[span[0] : span[1]]!r} -> {value[:20]!r}",
                _replace_span(text, span, value.encode()),
            )
        elif kind in ("delete", "repeat", "swap") and elements:
            found = _element_span(text, rng.choice(elements))
            if found is None:
                continue
            span = found
            piece = text[span[0] : span[1]]
            if kind == "delete":
                yield f"delete {piece[:30]!r}", _replace_span(text, span, b"")
            elif kind == "repeat":
                times = rng.choice((2, 3, 40))
                yield f"repeat {piece[:30]!r} x{times}", _replace_span(text, span, piece * times)
            else:
                other = _element_span(text, rng.choice(elements))
                if other is None or other[0] < span[1]:
                    continue
                yield f"swap {piece[:20]!r}", (
                    text[: span[0]] + text[other[0] : other[1]] + text[span[1] : other[0]]
                    + piece + text[other[1] :]
                )  # fmt: skip
        elif kind == "truncate":
            cut = rng.randrange(1, len(text))
            yield f"truncate at {cut}", text[:cut]
        elif kind == "utf8":
            at = rng.randrange(len(text))
            yield f"bad utf-8 at {at}", text[:at] + b"\xc3\x28\xff\xfe" + text[at:]
        elif kind == "nest" and elements:
            at = rng.choice(elements)
            depth = rng.choice((50, 300, 2000))
            yield f"nest x{depth}", text[:at] + b"<a>" * depth + b"</a>" * depth + text[at:]
