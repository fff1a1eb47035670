"""The project's own mutators: hostile and clumsy variants of the shipped bus configurations and
of ESI files, each with what a correct loader must do with it.

A :class:`Mutant` is the bytes of one file plus its verdict:

- ``nonsense`` mutants carry a value no field can take (true/false for a number, a number for
  true/false, NaN or infinity outside a limit, an integer wider than 64 bits, text with a NUL
  or a control character, a 5000-character value, a 0 scale, a ROS period beyond int64, an
  invalid namespace, an unknown key, a container where a plain value belongs). The loader must
  refuse them with an error naming ``field`` (the key path of the value);
- every other mutant (a value swapped for another plausible one, a key removed, the text cut,
  bytes flipped, an alias bomb, deep nesting, bad UTF-8) must end cleanly: accepted, or refused
  with the project's own error. Never a traceback, never a hang.

Mutants are made from a seed, so a run is repeatable: ``config_mutants(seed=1)`` gives the same
corpus on every machine. :mod:`ether_ros.testing.fuzzing` runs them in a worker process with a
time and memory bound; ``tests/unit/test_fuzz_config.py`` and ``test_fuzz_esi.py`` turn the
corpora into regression tests and ``make fuzz`` (``bench/fuzz.py``) runs longer ones.
"""

from __future__ import annotations

import math
import random
import re
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from ether_ros.config.esi import is_dictionary_file
from ether_ros.config.yamlsrc import KeyPath, format_path
from ether_ros.tools.vendor_corpus import vendor_dir

ROOT = Path(__file__).resolve().parents[3]
#: The shipped bus configurations the config mutants start from.
CONFIG_DIR = ROOT / "config"
#: The project's ESI files and its corpus; the vendor files are read where they are shared.
ESI_DIRS = (ROOT / "devices", ROOT / "tests" / "data" / "esi")
VENDOR_ESI_DIR: Path | None = vendor_dir()  # ../shared/esi-vendor, found as the tests find it


@dataclass(frozen=True)
class Mutant:
    """One mutated file: ``name`` says where it came from and what was done."""

    name: str
    data: bytes
    #: A value no field takes: the loader must refuse it, naming ``field``.
    nonsense: bool = False
    #: The key path (``slaves[0].joints[1].position_scale``) a refusal must name.
    field: str | None = None


# --------------------------------------------------------------------------------------- YAML

# Keys whose values may be infinite (a limit that is not there).
_LIMIT_KEYS = {"position_limits", "velocity_limit", "torque_limit", "deceleration"}
# Keys taking an integer that may also be written as text ("0x0A12").
_HEX_KEYS = {"index", "subindex", "alias", "vendor_id", "product_code", "revision", "serial"}


def _leaves(data: Any, path: KeyPath = ()) -> Iterator[tuple[KeyPath, Any]]:
    if isinstance(data, dict):
        for key, value in data.items():
            yield from _leaves(value, (*path, str(key)))
    elif isinstance(data, list):
        if data and all(not isinstance(v, dict | list) for v in data):
            yield path, data  # a list of plain values is one value (esi, pdo_assign.rx)
        for i, value in enumerate(data):
            yield from _leaves(value, (*path, i))
    else:
        yield path, data


def _replaced(data: Any, path: KeyPath, value: Any) -> Any:
    """A copy of ``data`` with the value at ``path`` replaced."""
    if not path:
        return value
    head, rest = path[0], path[1:]
    if isinstance(data, dict):
        key = next((k for k in data if str(k) == head), None)
        if key is None:  # a key the data does not have: added
            assert not rest
            return {**data, head: value}
        return {k: (_replaced(v, rest, value) if k == key else v) for k, v in data.items()}
    assert isinstance(data, list) and isinstance(head, int)
    return [_replaced(v, rest, value) if i == head else v for i, v in enumerate(data)]


def _removed(data: Any, path: KeyPath) -> Any:
    head, rest = path[0], path[1:]
    if not rest:
        if isinstance(data, dict):
            return {k: v for k, v in data.items() if str(k) != head}
        return [v for i, v in enumerate(data) if i != head]
    if isinstance(data, dict):
        return {k: (_removed(v, rest) if str(k) == head else v) for k, v in data.items()}
    return [_removed(v, rest) if i == head else v for i, v in enumerate(data)]


def _deep(levels: int) -> Any:
    value: Any = 1
    for _ in range(levels):
        value = [value]
    return value


def _nonsense_values(path: KeyPath, value: Any) -> list[tuple[str, Any]]:
    """(label, value) pairs no field at ``path`` (holding ``value`` now) may take."""
    key = next((p for p in reversed(path) if isinstance(p, str)), "")
    # Values typed by the device (a process variable, an SDO object): 0/1 is a BOOL's value
    # there, and true/false a number's only where the variable is a BOOL.
    device_typed = "safe_outputs" in path or (key == "value" and "sdo_init" in path)
    out: list[tuple[str, Any]] = [
        ("wider than 64 bits", 2**70),
        ("a 5000-character text", "x" * 5000),
        ("nested 40 deep", _deep(40)),
    ]
    if isinstance(value, bool):
        out.append(("text 'yes'", "yes"))
        if not device_typed:
            out += [("1 for true/false", 1), ("0 for true/false", 0)]
    elif isinstance(value, int | float):
        out.append(("NaN", math.nan))
        if not device_typed:
            out += [("true for a number", True), ("false for a number", False)]
        if key not in _LIMIT_KEYS:
            out += [("infinity", math.inf), ("minus infinity", -math.inf)]
        if key not in _HEX_KEYS:
            out.append(("text for a number", "twelve"))
        if key.endswith("_scale"):
            out.append(("a scale of 0", 0.0))
        if key in ("snapshot_period_ms", "raw_decimation", "decoded_decimation"):
            out.append(("beyond int64 in ns", 2**62))
        out.append(("a mapping for a number", {"a": 1}))
    elif isinstance(value, str):
        out += [
            ("a NUL inside", value[:3] + "\0" + value[3:]),
            ("an escape sequence", "\x1b[31m" + value),
            ("a right-to-left override", value + "\u202e"),
            ("a list for text", [value, value]),
        ]
        if key == "namespace":
            out += [("namespace part starting with a digit", "/1robot"), ("a//b", "/a//b")]
        if key in ("name", "node_name"):
            out += [("blanks in a name", "front leg"), ("upper case in a name", "Leg")]
        if key == "interface":
            out += [("a / in an interface", "eth/0"), ("an interface of 16", "e" * 16)]
    return out


def _plausible_values(value: Any) -> list[tuple[str, Any]]:
    """Values that may or may not suit the field: the loader may take or refuse them."""
    out: list[tuple[str, Any]] = [("null", None), ("empty text", ""), ("-1", -1), ("0", 0)]
    if isinstance(value, int) and not isinstance(value, bool):
        out += [("+1", value + 1), ("65535", 65535), ("2**32", 2**32), ("0.5", 0.5)]
    if isinstance(value, float):
        out += [("1e300", 1e300), ("-1e-300", -1e-300)]
    if isinstance(value, str):
        out += [("upper case", value.upper()), ("unicode", value + "é"), ("blank", " ")]
    if isinstance(value, list):
        out += [("empty list", []), ("list doubled", value + value)]
    return out


def _huge_values(value: Any) -> list[tuple[str, Any]]:
    """The float extremes a number may be given: taken or refused, never an overflow (a scale
    of 1e-308 turned a position limit into infinity, and its conversion to counts into an
    OverflowError)."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        return []
    return [("1e308", 1e308), ("-1e308", -1e308), ("1e-308", 1e-308)]


def _dump(data: Any) -> bytes:
    # allow_unicode so that NUL and escapes stay escapes in double quotes; width: one line
    return yaml.safe_dump(data, sort_keys=False, allow_unicode=True, width=10_000).encode()


def _absolute_esi(data: dict[str, Any], base: Path) -> dict[str, Any]:
    """The config with its ``esi`` paths made absolute, so a mutant runs from any folder."""
    esi = data.get("esi", [])
    items = [esi] if isinstance(esi, str) else list(esi)
    return {**data, "esi": [str((base / item).resolve()) for item in items]}


def config_mutants(
    seed: int = 1, leaves_per_file: int = 16, files: list[Path] | None = None
) -> list[Mutant]:
    """Mutants of the shipped configurations (``config/*.yaml``): on ``leaves_per_file`` values
    per file (drawn with ``seed``), every nonsense value and a few plausible ones; keys removed
    and added; and text mutations of every file."""
    rng = random.Random(seed)
    out: list[Mutant] = []
    for file in files or sorted(CONFIG_DIR.glob("*.yaml")):
        base = _absolute_esi(yaml.safe_load(file.read_text()), file.parent)
        text = _dump(base)
        leaves = [(p, v) for p, v in _leaves(base) if p]
        chosen = rng.sample(leaves, min(leaves_per_file, len(leaves)))
        for path, value in chosen:
            field = format_path(path)
            for label, bad in _nonsense_values(path, value):
                out.append(
                    Mutant(
                        f"{file.name}:{field}={label}",
                        _dump(_replaced(base, path, bad)),
                        nonsense=True,
                        field=field,
                    )
                )
            for label, maybe in rng.sample(_plausible_values(value), 3):
                out.append(
                    Mutant(f"{file.name}:{field}={label}", _dump(_replaced(base, path, maybe)))
                )
            for label, huge in _huge_values(value):  # every number: an overflow is a traceback
                out.append(
                    Mutant(f"{file.name}:{field}={label}", _dump(_replaced(base, path, huge)))
                )
            out.append(Mutant(f"{file.name}:{field} removed", _dump(_removed(base, path))))
            parent = path[:-1]
            if isinstance(path[-1], str):
                unknown = (*parent, "colour")
                out.append(
                    Mutant(
                        f"{file.name}:{format_path(unknown)} added",
                        _dump(_replaced(base, unknown, 1)),
                        nonsense=True,
                        field=format_path(unknown),
                    )
                )
        out += _text_mutants(file.name, text, rng)
    return out


def _text_mutants(name: str, text: bytes, rng: random.Random) -> list[Mutant]:
    """Mutations of the file as bytes: cuts, flipped bytes, bad encodings, YAML features a
    configuration has no use for."""
    out: list[Mutant] = []
    for cut in sorted(rng.sample(range(1, len(text)), min(8, len(text) - 1))):
        out.append(Mutant(f"{name}: cut at byte {cut}", text[:cut]))
    for _ in range(8):
        at = rng.randrange(len(text))
        flipped = bytes([text[at] ^ (1 << rng.randrange(8))])
        out.append(
            Mutant(f"{name}: bit flipped at byte {at}", text[:at] + flipped + text[at + 1 :])
        )
    at = rng.randrange(len(text))
    out += [
        Mutant(f"{name}: NUL byte at {at}", text[:at] + b"\0" + text[at:]),
        Mutant(f"{name}: invalid UTF-8 at {at}", text[:at] + b"\xff\xfe" + text[at:]),
        Mutant(f"{name}: UTF-16", text.decode().encode("utf-16")),
        Mutant(f"{name}: CRLF line ends", text.replace(b"\n", b"\r\n")),
        Mutant(f"{name}: tab indentation", text.replace(b"  ", b"\t")),
        Mutant(f"{name}: a second document", text + b"---\n" + text),
        Mutant(
            f"{name}: a 5000-digit integer",
            re.sub(rb": \d+\n", b": " + b"7" * 5000 + b"\n", text, count=1),
        ),
        Mutant(f"{name}: alias bomb", _alias_bomb() + text),
        Mutant(f"{name}: recursive alias", b"loop: &a [*a]\n" + text),
        Mutant(
            f"{name}: nested 10000 deep", b"deep: " + b"[" * 10_000 + b"]" * 10_000 + b"\n" + text
        ),
        Mutant(f"{name}: !!python/object tag", b"x: !!python/object:os.system ls\n" + text),
        Mutant(f"{name}: !!binary value", text.replace(b"name: ", b"name: !!binary aGVsbG8= #", 1)),
        Mutant(f"{name}: a top-level list", b"- " + text.replace(b"\n", b"\n  ")),
        Mutant(f"{name}: empty", b""),
    ]
    return out


def _alias_bomb(levels: int = 9) -> bytes:
    """The billion laughs in YAML: each anchor lists the previous one nine times."""
    lines = ["bomb0: &b0 [lol, lol, lol, lol, lol, lol, lol, lol, lol]"]
    for n in range(1, levels):
        refs = ", ".join([f"*b{n - 1}"] * 9)
        lines.append(f"bomb{n}: &b{n} [{refs}]")
    return ("\n".join(lines) + "\n").encode()


# ---------------------------------------------------------------------------------------- ESI

# Elements and attributes of an ESI that hold unsigned numbers, with their width in bits
# (ETG.2000: indices 16, subindices 8, identity 32 ...): a value beyond the width, negative,
# not a number, or a number in no syntax the ESI has is one no such field can take. "0x10"
# is not in the list: vendors write C hex and the parser reads it as such.
_ESI_NUMBER_BITS = {
    "Index": 16,
    "SubIndex": 8,
    "SubIdx": 8,
    "BitLen": 16,
    "BitSize": 16,
    "BitOffs": 16,
    "DefaultSize": 16,
    "StartAddress": 16,
    "ControlByte": 8,
    "Enable": 8,
    "VendorId": 32,
    "ProductCode": 32,
    "RevisionNo": 32,
    "Sm": 8,
    "Elements": 16,
    "ByteSize": 32,
    "CycleTimeSync0": 32,
    "AssignActivate": 16,
    "ProfileNo": 32,
    "Id": 32,
}
_ESI_TAGS = tuple(_ESI_NUMBER_BITS)
_ESI_NOT_A_NUMBER = ("-1", "#x-1", "twelve", "", "#x", "1.5", "9" * 5000, "#x" + "F" * 20)


def _esi_bad_numbers(tag: str) -> list[str]:
    """Values the number field ``tag`` can never take."""
    width = _ESI_NUMBER_BITS[tag]
    return [*_ESI_NOT_A_NUMBER, str(1 << width), f"#x{1 << width:X}"]


def esi_files(include_vendor: bool = True, max_bytes: int | None = None) -> list[Path]:
    """The ESI files the mutators start from: the project's, its corpus, and (when present)
    the shared vendor files, read in place."""
    vendor = [VENDOR_ESI_DIR] if include_vendor and VENDOR_ESI_DIR is not None else []
    dirs = list(ESI_DIRS) + vendor
    files = sorted(
        p for d in dirs if d.is_dir() for p in d.rglob("*.xml") if not is_dictionary_file(p)
    )
    if max_bytes is not None:
        files = [p for p in files if p.stat().st_size <= max_bytes]
    return files


def esi_mutants(seed: int = 1, per_file: int = 24, files: list[Path] | None = None) -> list[Mutant]:
    """Mutants of ESI files: number fields set to values none can take, elements removed or
    repeated, counts blown up, the text cut or broken."""
    rng = random.Random(seed)
    out: list[Mutant] = []
    for file in files if files is not None else esi_files(max_bytes=500_000):
        data = file.read_bytes()
        name = file.name
        number_spans = _esi_number_spans(data)
        for start, end, tag in rng.sample(number_spans, min(per_file, len(number_spans))):
            bad = rng.choice(_esi_bad_numbers(tag)).encode()
            out.append(
                Mutant(
                    f"{name}:{tag}@{start}={bad[:12]!r}",
                    data[:start] + bad + data[end:],
                    nonsense=True,
                    field=tag,
                )
            )
        out += _esi_structure_mutants(name, data, rng)
    return out


_NUMBER_RE = re.compile(
    rb"<(" + b"|".join(t.encode() for t in _ESI_TAGS) + rb")>([^<]{1,40})</\1>"
    rb"|\b(" + b"|".join(t.encode() for t in _ESI_TAGS) + rb')="([^"]{0,40})"'
)


def _esi_number_spans(data: bytes) -> list[tuple[int, int, str]]:
    """(start, end, tag) of the text of every number element or attribute."""
    spans = []
    for m in _NUMBER_RE.finditer(data):
        group = 2 if m.group(1) else 4
        spans.append((m.start(group), m.end(group), (m.group(1) or m.group(3)).decode()))
    return spans


def _esi_structure_mutants(name: str, data: bytes, rng: random.Random) -> list[Mutant]:
    out: list[Mutant] = []
    for tag in (b"Entry", b"Object", b"Sm", b"RxPdo", b"TxPdo", b"DataType", b"Device"):
        opens = [m.start() for m in re.finditer(rb"<" + tag + rb"[ >]", data)]
        if not opens:
            continue
        at = rng.choice(opens)
        close = data.find(b"</" + tag + b">", at)
        if close < 0:
            continue
        end = close + len(tag) + 3
        element = data[at:end]
        out.append(Mutant(f"{name}: <{tag.decode()}> @{at} removed", data[:at] + data[end:]))
        out.append(
            Mutant(
                f"{name}: <{tag.decode()}> @{at} repeated", data[:end] + element * 3 + data[end:]
            )
        )
        if tag in (b"RxPdo", b"TxPdo", b"Object"):
            out.append(
                Mutant(
                    f"{name}: <{tag.decode()}> @{at} 3000 times",
                    data[:end] + element * 3000 + data[end:],
                )
            )
    for cut in sorted(rng.sample(range(1, len(data)), 4)):
        out.append(Mutant(f"{name}: cut at byte {cut}", data[:cut]))
    at = rng.randrange(len(data))
    out += [
        Mutant(f"{name}: invalid UTF-8 at {at}", data[:at] + b"\xc3\x28\xff" + data[at:]),
        Mutant(f"{name}: NUL byte at {at}", data[:at] + b"\0" + data[at:]),
        Mutant(
            f"{name}: entity declaration",
            b'<?xml version="1.0"?>\n<!DOCTYPE x [<!ENTITY a "aaaaaaaaaa">'
            b'<!ENTITY b "&a;&a;&a;&a;&a;&a;&a;&a;&a;&a;">]>\n'
            + re.sub(rb"<\?xml[^>]*\?>", b"", data, count=1),
        ),
        Mutant(
            f"{name}: nested 5000 deep",
            data.replace(
                b"</EtherCATInfo>", b"<a>" * 5000 + b"</a>" * 5000 + b"</EtherCATInfo>", 1
            ),
        ),
        Mutant(
            f"{name}: ArrayInfo of 10^9",
            re.sub(rb"<Elements>\d+</Elements>", b"<Elements>1000000000</Elements>", data, count=1),
        ),
        Mutant(
            f"{name}: BitSize of 2^40",
            re.sub(rb"<BitSize>\d+</BitSize>", b"<BitSize>1099511627776</BitSize>", data, count=1),
        ),
    ]
    return out
