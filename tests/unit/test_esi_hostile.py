"""Hostile and broken ESI files (issue 19): no traceback, no hang, no nonsense accepted. Every
error or warning is one line naming file, line and element; what a broken file still yields
can be turned into an SII image, a simulator spec and a process layout without anything but a
ConfigError; paths that are not regular files are refused before anything is read; counts and
sizes are bounded."""

from __future__ import annotations

import os
import re
from pathlib import Path

import pytest

from ether_ros.config import ProcessLayout, build_sii
from ether_ros.config.esi import (
    MAX_DEVICES,
    MAX_ESI_BYTES,
    EsiDevice,
    load_esi,
    load_esi_file,
    parse_esi_int,
)
from ether_ros.errors import ConfigError
from ether_ros.sim.spec import device_spec
from ether_ros.testing.mutants import esi_mutants

REPO = Path(__file__).resolve().parents[2]
SOURCES = sorted((REPO / "tests" / "data" / "esi").glob("*.xml")) + sorted(
    (REPO / "devices").glob("*.xml")
)
SEED = 20_250_601
PER_FILE = 64


def _one_line(text: str, path: Path) -> None:
    assert "\n" not in text, text
    assert re.match(rf"^{re.escape(str(path))}:\d+(:\d+)?: ", text) or text.startswith(
        f"{path}: "
    ), text


@pytest.mark.parametrize("source", SOURCES, ids=[s.name for s in SOURCES])
def test_mutants_load_or_fail_with_one_line(source: Path, tmp_path: Path) -> None:
    corpus = esi_mutants(seed=SEED + SOURCES.index(source), per_file=PER_FILE, files=[source])
    for k, mutant in enumerate(corpus):
        what, data = mutant.name, mutant.data
        p = tmp_path / f"mutant{k}.xml"
        p.write_bytes(data)
        try:
            esi = load_esi_file(p)
        except ConfigError as exc:
            _one_line(str(exc), p)
            continue
        for w in esi.warnings:
            _one_line(str(w), p)
        for d in esi.devices:
            if d.passive:
                continue
            for make in (
                lambda d=d: build_sii(d),
                lambda d=d: _simulate(d),
                lambda d=d: ProcessLayout.for_device(d),
            ):
                try:
                    make()
                except ConfigError as exc:
                    assert "\n" not in str(exc), (what, str(exc))


def _simulate(device: EsiDevice) -> None:
    """The device as a virtual slave: the spec, and the simulator taking it (a device the chip
    cannot carry is refused with a ValueError naming why; nothing else may come out)."""
    from ether_ros._native import SimNetwork

    spec = device_spec(device, name="m", sim_device="loopback")
    try:
        SimNetwork(seed=1).add_slave(spec)
    except ValueError as exc:
        assert "cannot emulate" in str(exc), str(exc)


@pytest.mark.parametrize(
    "text",
    ["", " ", "1_000", "+", "#x", "0x", "#xG", "1e3", "1.0", "١٢", "9" * 5000, "#x" + "F" * 17,
     "NaN", "0x-1", "--1", "\u00a07"],
)  # fmt: skip
def test_esi_numbers_are_strict(text: str) -> None:
    with pytest.raises(ValueError):
        parse_esi_int(text)


def test_esi_numbers_that_are_numbers() -> None:
    assert [parse_esi_int(t) for t in ("#x1A00", "0x1a00", " 6656 ", "-5", "+5")] == [
        0x1A00, 0x1A00, 6656, -5, 5
    ]  # fmt: skip


DEVICE = """<?xml version="1.0"?>
<EtherCATInfo><Vendor><Id>2</Id></Vendor><Descriptions><Devices>
<Device><Type ProductCode="#x10" RevisionNo="1">D</Type><Name>D</Name>
<Sm StartAddress="{start}" ControlByte="{control}" Enable="1">Inputs</Sm>
<TxPdo Sm="0"><Index>{pdo}</Index><Name>P</Name>
<Entry><Index>#x6000</Index><SubIndex>{sub}</SubIndex><BitLen>{bits}</BitLen><Name>E</Name><DataType>USINT</DataType></Entry>
</TxPdo>
<Dc><OpMode><Name>DC</Name><AssignActivate>{aa}</AssignActivate></OpMode></Dc>
<Eeprom><ByteSize>{size}</ByteSize></Eeprom>
</Device></Devices></Descriptions></EtherCATInfo>
"""
GOOD = {"start": "#x1000", "control": "#x20", "pdo": "#x1A00", "sub": "1", "bits": "8",
        "aa": "#x0300", "size": "2048"}  # fmt: skip
NONSENSE = [
    ("start", "#x10000", r"<Sm>: attribute StartAddress out of range"),
    ("control", "256", r"<Sm>: attribute ControlByte out of range"),
    ("pdo", "-1", r"<Index>: out of range"),
    ("sub", "300", r"<SubIndex>: out of range"),
    ("bits", "0", r"<BitLen>: out of range"),
    ("bits", "70000", r"<BitLen>: out of range"),
    ("bits", "16", r"<Entry>: BitLen 16 does not match data type USINT"),
    ("aa", "#x10000", r"<AssignActivate>: out of range"),
    ("size", "1099511627776", r"<ByteSize>: out of range"),
    ("sub", "1_0", r"<SubIndex>: not a number"),
]


@pytest.mark.parametrize(("key", "value", "pattern"), NONSENSE)
def test_nonsense_values_are_refused_naming_the_element(
    tmp_path: Path, key: str, value: str, pattern: str
) -> None:
    p = tmp_path / "d.xml"
    p.write_text(DEVICE.format(**{**GOOD, key: value}))
    esi = load_esi_file(p)
    lines = [str(w) for w in esi.warnings]
    assert any(re.search(pattern, w) for w in lines), lines
    for w in lines:
        _one_line(w, p)


def test_a_fifo_a_device_and_a_directory_are_refused_before_reading(tmp_path: Path) -> None:
    fifo = tmp_path / "pipe.xml"
    os.mkfifo(fifo)
    # A FIFO nobody writes to would block a reader forever: refused without opening it.
    with pytest.raises(ConfigError, match=r"pipe\.xml: not a regular file"):
        load_esi(fifo)
    with pytest.raises(ConfigError, match=r"/dev/zero: not a regular file"):
        load_esi("/dev/zero")
    with pytest.raises(ConfigError, match=r": not a regular file"):
        load_esi(tmp_path)
    big = tmp_path / "big.xml"
    with open(big, "wb") as f:
        f.truncate(MAX_ESI_BYTES + 1)
    with pytest.raises(ConfigError, match=r"big\.xml: \d+ bytes, more than an ESI may have"):
        load_esi(big)


def test_a_200k_entry_pdo_is_skipped_by_its_count(tmp_path: Path) -> None:
    entry = (
        "<Entry><Index>#x6000</Index><SubIndex>1</SubIndex><BitLen>8</BitLen><Name>E</Name>"
        "<DataType>USINT</DataType></Entry>"
    )
    text = DEVICE.format(**GOOD).replace("<Entry>", entry * 200_000 + "<Entry>", 1)
    p = tmp_path / "wide.xml"
    p.write_text(text)
    esi = load_esi_file(p)
    (dev,) = esi.devices
    assert dev.tx_pdos == ()
    assert any("more than 255 entries in one PDO" in str(w) for w in esi.warnings)


def test_thousands_of_devices_are_refused_by_their_count(tmp_path: Path) -> None:
    one = DEVICE.format(**GOOD)
    device = one[one.index("<Device>") : one.index("</Devices>")]
    text = one.replace("</Devices>", device * 3000 + "</Devices>", 1)
    p = tmp_path / "many.xml"
    p.write_text(text)
    with pytest.raises(ConfigError, match=rf"more than {MAX_DEVICES} devices in one file"):
        load_esi(p)


def test_deep_nesting_and_bad_utf8_are_one_line_errors(tmp_path: Path) -> None:
    deep = tmp_path / "deep.xml"
    deep.write_text("<EtherCATInfo>" + "<a>" * 5000 + "</a>" * 5000 + "</EtherCATInfo>")
    with pytest.raises(ConfigError) as info:
        load_esi(deep)
    _one_line(str(info.value), deep)
    bad = tmp_path / "bad.xml"
    bad.write_bytes(DEVICE.format(**GOOD).encode().replace(b"<Name>D</Name>", b"<Name>\xff</Name>"))
    with pytest.raises(ConfigError) as info:
        load_esi(bad)
    _one_line(str(info.value), bad)
