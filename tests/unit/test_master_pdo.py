"""PDO selection from the ESI / the configuration override, and the CoE writes it needs."""

from __future__ import annotations

import struct
from pathlib import Path

import pytest

from ether_ros.config import load_esi
from ether_ros.config.esi import EsiDevice
from ether_ros.errors import BusError
from ether_ros.master.configure import process_fmmus, process_sync_managers
from ether_ros.master.pdo import RX_ASSIGN, TX_ASSIGN, assignment_writes, select_pdos
from ether_ros.master.plan import layout_image

DEVICES = Path(__file__).resolve().parents[2] / "devices"


@pytest.fixture(scope="module")
def leg() -> EsiDevice:
    return load_esi(DEVICES / "laelaps_ii_leg.xml")[0]


def test_esi_default_assignment_sizes(leg: EsiDevice) -> None:
    sel = select_pdos("slave 0 (leg)", leg)
    assert sel.source == "esi"
    assert sel.output_bytes == 38 and sel.input_bytes == 22


def test_override_is_checked_against_the_esi(leg: EsiDevice) -> None:
    rx = [p.index for p in leg.rx_pdos if p.sm is not None]
    tx = [p.index for p in leg.tx_pdos if p.sm is not None]
    sel = select_pdos("slave 0 (leg)", leg, rx, tx)
    assert sel.source == "config"
    with pytest.raises(BusError, match=r"slave 0 \(leg\): PDO 0x1234 is not in the ESI"):
        select_pdos("slave 0 (leg)", leg, [0x1234], tx)
    with pytest.raises(BusError, match="is a TxPDO"):
        select_pdos("slave 0 (leg)", leg, tx, tx)


def test_assignment_writes_clear_fill_count(leg: EsiDevice) -> None:
    sel = select_pdos("s", leg)
    writes = assignment_writes(sel, write_mapping=False)
    rx = [(w.index, w.subindex, w.data) for w in writes if w.index == RX_ASSIGN]
    assert rx[0] == (RX_ASSIGN, 0, b"\0")
    assert rx[-1] == (RX_ASSIGN, 0, bytes([len(sel.rx)]))
    assert [struct.unpack("<H", d)[0] for _i, s, d in rx[1:-1]] == [p.index for p in sel.rx]
    assert any(w.index == TX_ASSIGN for w in writes)
    with_mapping = assignment_writes(sel, write_mapping=True)
    mapping = [w for w in with_mapping if w.index == sel.rx[0].index and w.subindex == 1]
    if not sel.rx[0].fixed:
        entry = sel.rx[0].entries[0]
        assert mapping[0].data == struct.pack("<I", entry.mapping_value)


def test_process_sms_and_fmmus_from_esi(leg: EsiDevice) -> None:
    layout = layout_image([(0, 0x1001, "a", 38, 22), (1, 0x1002, "b", 38, 22)])
    sms = process_sync_managers(leg, 38, 22)
    assert [(s.index, s.start, s.length, s.control) for s in sms] == [
        (2, 0x1100, 38, 0x64),
        (3, 0x1400, 22, 0x20),
    ]
    fmmus = process_fmmus(layout.slaves[1], sms, 0)
    assert [(f.logical_start, f.length, f.physical_start, f.direction) for f in fmmus] == [
        (38, 38, 0x1100, 2),
        (76 + 22, 22, 0x1400, 1),
    ]
