"""The inspector against the in-process simulator: the fallbacks a real bus may force (no SDO
information, no CoE) and the pieces that need no bus at all."""

from __future__ import annotations

import dataclasses
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from ether_ros.config import load_bus_config
from ether_ros.config.esi import load_esi
from ether_ros.config.sii import build_sii, parse_sii
from ether_ros.sim.network import build_network
from ether_ros.tools.bus_inspect import InspectError, Inspector, esi_from_sii

REPO = Path(__file__).resolve().parents[2]
GENERIC = REPO / "config" / "generic_io.yaml"


@pytest.fixture
def inspector() -> Iterator[Inspector]:
    cfg = load_bus_config(GENERIC)
    with Inspector.open(link=build_network(cfg), config=str(GENERIC)) as ins:
        yield ins


def without(ins: Inspector, position: int, **changes: Any) -> None:
    """Make the slave's SII say less than it does (what an older device would report)."""
    f = ins.found[position]
    header = f.header
    if "coe_details" in changes:
        general = dataclasses.replace(header.general, coe_details=changes.pop("coe_details"))
        changes["general"] = general
    f.header = dataclasses.replace(header, **changes)


def test_dictionary_falls_back_to_the_esi(inspector: Inspector) -> None:
    source, objects = inspector.dictionary("io_a")
    assert source == "sdo-info"
    without(inspector, 0, coe_details=0x01)  # SDO, but no SDO information service
    source, esi_objects = inspector.dictionary("io_a")
    assert source == "esi"
    assert {o["index"] for o in esi_objects} >= {
        o["index"] for o in objects if o["index"] >= 0x6000
    }


def test_pdos_from_the_sii_without_coe(inspector: Inspector) -> None:
    assert inspector.pdos("io_b")["source"] == "coe"
    without(inspector, 1, mailbox_protocols=0)
    pdos = inspector.pdos("io_b")
    assert pdos["source"] == "sii"
    assert [p["index"] for p in pdos["rx_pdos"]] == [
        p.index for p in inspector.found[1].header.rx_pdos
    ]


def test_typed_round_trip_and_errors(inspector: Inspector) -> None:
    ref, data = inspector.download("io_a", "DigitalOutput1", "true")
    assert (ref.index, ref.subindex, data) == (0x7000, 1, b"\x01")
    assert inspector.upload("io_a", "DigitalOutput1")[2] is True
    with pytest.raises(InspectError, match="no slave 'io_c'"):
        inspector.slave("io_c")
    with pytest.raises(InspectError, match="out of range"):
        inspector.resolve_object("io_a", "0x10000:1")
    with pytest.raises(InspectError, match="bool needs true/false"):
        inspector.download("io_a", "DigitalOutput1", "maybe")
    with pytest.raises(InspectError, match="SAFEOP needs the process data"):
        inspector.request_state("SAFEOP")
    assert [s["state"] for s in inspector.request_state("preop")] == ["PREOP", "PREOP"]


def test_topology_from_the_scans_dl_status(inspector: Inspector) -> None:
    # The tree builder itself: tests/unit/test_topology.py.
    nodes = inspector.topology()
    assert [(n["parent"], n["port"], n["open_ports"]) for n in nodes] == [
        (None, 0, [0, 1]),
        (0, 1, [0]),
    ]
    assert 'slave0 -> slave1 [label="port 1"];' in inspector.graph_dot()


def test_esi_from_sii_round_trips_the_shipped_device(tmp_path: Path) -> None:
    for xml in ("laelaps_ii_leg.xml", "generic_io.xml"):
        device = load_esi(REPO / "devices" / xml)[0]
        out = tmp_path / xml
        out.write_text(esi_from_sii(parse_sii(build_sii(device))))
        again = load_esi(out)[0]
        assert (again.vendor_id, again.product_code, again.revision) == (
            device.vendor_id,
            device.product_code,
            device.revision,
        )
        assert [
            (p.index, [(e.index, e.subindex, e.bit_length) for e in p.entries])
            for p in again.rx_pdos + again.tx_pdos
        ] == [
            (p.index, [(e.index, e.subindex, e.bit_length) for e in p.entries])
            for p in device.rx_pdos + device.tx_pdos
        ]
        assert [(s.start, s.control) for s in again.sync_managers] == [
            (s.start, s.control) for s in device.sync_managers
        ]
