"""The SDO client against the real simulator in process: one virtual slave built from the generic
I/O ESI (plus a few test objects), brought to PREOP with raw datagrams through
``SimNetwork.process_frame``, then SDO transfers of every kind through the real ESC mailbox and
the Rust CoE server."""

from __future__ import annotations

import struct
from pathlib import Path
from typing import Any

import pytest

from ether_ros.errors import MailboxError
from ether_ros.master.coe import SdoClient
from ether_ros.master.mailbox import Mailbox

native = pytest.importorskip("ether_ros._native")
if not hasattr(native, "SimNetwork"):
    pytest.skip("the simulator (SimNetwork) is not built yet", allow_module_level=True)

from ether_ros.config.esi import EsiDevice, load_esi  # noqa: E402
from ether_ros.config.sii import build_sii  # noqa: E402

ESI = Path(__file__).resolve().parents[2] / "devices" / "generic_io.xml"
STATION = 0x1001
MASTER_MAC = bytes([0x02, 0, 0, 0, 0, 0x01])
DEVICE_NAME = "a long device name that needs segmented transfers " * 6


class FrameDatagrams:
    """The ``Datagrams`` protocol on ``SimNetwork.process_frame``: one datagram per frame, laid
    out as in crates/wire (Ethernet II, EtherType 0x88A4, EtherCAT header, datagram, WKC)."""

    FPRD, FPWR, APWR, APRD = 4, 5, 2, 1

    def __init__(self, net: Any) -> None:
        self.net = net
        self.index = 0

    def transact(self, cmd: int, address: int, data: bytes) -> tuple[bytes, int]:
        self.index = (self.index + 1) & 0xFF
        datagram = struct.pack("<BBIHH", cmd, self.index, address, len(data), 0) + data + b"\0\0"
        ecat = struct.pack("<H", len(datagram) | 0x1000)
        frame = b"\xff" * 6 + MASTER_MAC + b"\x88\xa4" + ecat + datagram
        reply = self.net.process_frame(frame.ljust(60, b"\x00"))
        if reply is None:
            return bytes(len(data)), 0
        body = reply[16 : 16 + len(datagram)]
        assert body[1] == self.index
        return body[10 : 10 + len(data)], struct.unpack_from("<H", body, 10 + len(data))[0]

    def fprd(self, station: int, ado: int, length: int) -> tuple[bytes, int]:
        return self.transact(self.FPRD, station | ado << 16, bytes(length))

    def fpwr(self, station: int, ado: int, data: bytes) -> int:
        return self.transact(self.FPWR, station | ado << 16, data)[1]

    def apwr(self, position: int, ado: int, data: bytes) -> int:
        return self.transact(self.APWR, (-position & 0xFFFF) | ado << 16, data)[1]


def spec_for(device: EsiDevice, mbx: native.MailboxSpec) -> native.SlaveSpec:
    objects: list[tuple[int, str, int]] = []
    entries: list[tuple[int, int, str, int, int, str, bool, bytes]] = []
    for o in device.objects:
        objects.append((o.index, o.name, o.object_code))
        for e in o.entries:
            bits = e.bit_length or 8
            entries.append(
                (e.index, e.subindex, e.name, e.data_type, bits, e.access, e.pdo_mappable,
                 e.default)
            )  # fmt: skip
    # Test objects: a long read-only string, a writable octet string, a write-only u32, and a
    # configurable RxPDO assignment with a free mapping object 0x1602.
    objects += [(0x1008, "Device name", 7), (0x2100, "Blob", 7), (0x2101, "Secret", 7)]
    objects += [(0x1602, "Spare RxPDO", 9)]
    entries = [e for e in entries if e[0] != 0x1C12]
    entries += [
        (0x1008, 0, "Device name", 0x09, 8 * len(DEVICE_NAME), "ro", False, DEVICE_NAME.encode()),
        (0x2100, 0, "Blob", 0x0A, 8 * 300, "rw", False, b""),
        (0x2101, 0, "Secret", 0x07, 32, "wo", False, b""),
        (0x1C12, 0, "SubIndex 000", 0x05, 8, "rw", False, b"\x02"),
        (0x1C12, 1, "SubIndex 001", 0x06, 16, "rw", False, b"\x00\x16"),
        (0x1C12, 2, "SubIndex 002", 0x06, 16, "rw", False, b"\x01\x16"),
        (0x1C12, 3, "SubIndex 003", 0x06, 16, "rw", False, b""),
        (0x1602, 0, "SubIndex 000", 0x05, 8, "rw", False, b""),
        (0x1602, 1, "SubIndex 001", 0x07, 32, "rw", False, b""),
        (0x1602, 2, "SubIndex 002", 0x07, 32, "rw", False, b""),
    ]
    return native.SlaveSpec(
        name="front_left_leg",
        vendor_id=device.vendor_id,
        product_code=device.product_code,
        revision=device.revision,
        sii=build_sii(device),
        objects=objects,
        entries=entries,
        device="none",
        mailbox=mbx,
    )


def open_sim_slave() -> SdoClient:
    """A simulator with one slave in PREOP and an SDO client for it."""
    device = load_esi(ESI)[0]
    mbox_out, mbox_in = device.sm("MBoxOut"), device.sm("MBoxIn")
    assert mbox_out is not None and mbox_in is not None
    mbx = native.MailboxSpec(
        rx_offset=mbox_out.start,
        rx_size=mbox_out.default_size,
        tx_offset=mbox_in.start,
        tx_size=mbox_in.default_size,
    )
    net = native.SimNetwork()
    net.add_slave(spec_for(device, mbx))
    dg = FrameDatagrams(net)
    assert dg.apwr(0, 0x0010, struct.pack("<H", STATION)) == 1
    # SM0 write mailbox (control 0x26), SM1 read mailbox (control 0x22), both activated.
    sm0 = struct.pack("<HHBBBB", mbx.rx_offset, mbx.rx_size, 0x26, 0, 1, 0)
    sm1 = struct.pack("<HHBBBB", mbx.tx_offset, mbx.tx_size, 0x22, 0, 1, 0)
    assert dg.fpwr(STATION, 0x0800, sm0 + sm1) == 1
    assert dg.fpwr(STATION, 0x0120, struct.pack("<H", 0x02)) == 1
    for _ in range(100):
        status, _wkc = dg.fprd(STATION, 0x0130, 2)
        if status[0] & 0x0F == 0x02:
            break
    else:
        code, _ = dg.fprd(STATION, 0x0134, 2)
        raise AssertionError(f"no PREOP: AL status {status.hex()}, code {code.hex()}")
    mailbox = Mailbox(
        dg, STATION, "front_left_leg", mbx.rx_offset, mbx.rx_size,
        mbx.tx_offset, mbx.tx_size,
    )  # fmt: skip
    return SdoClient(mailbox, "front_left_leg", timeout_s=1.0)


@pytest.fixture
def sdo() -> SdoClient:
    return open_sim_slave()


def test_expedited_and_segmented_upload(sdo: SdoClient) -> None:
    identity = sdo.upload(0x1018, 1)
    assert len(identity) == 4
    assert sdo.upload(0x1008, 0) == DEVICE_NAME.encode()


def test_download_expedited_normal_segmented(sdo: SdoClient) -> None:
    sdo.download(0x2101, 0, b"\x01\x02\x03\x04")
    blob = bytes((i * 13) & 0xFF for i in range(300))
    sdo.download(0x2100, 0, blob)
    assert sdo.upload(0x2100, 0) == blob
    small = b"short blob"
    sdo.download(0x2100, 0, small)
    assert sdo.upload(0x2100, 0) == small.ljust(300, b"\x00")


def test_aborts(sdo: SdoClient) -> None:
    with pytest.raises(MailboxError) as e:
        sdo.upload(0x5555, 1)
    assert str(e.value) == (
        "slave 'front_left_leg': SDO upload 0x5555:01 aborted: "
        "0x06020000 object does not exist in the object dictionary"
    )
    with pytest.raises(MailboxError, match="0x06010001 attempt to read a write-only object"):
        sdo.upload(0x2101, 0)
    with pytest.raises(MailboxError, match="0x06010002 attempt to write a read-only object"):
        sdo.download(0x1008, 0, b"x" * 8)
    with pytest.raises(MailboxError, match="0x06070012"):
        sdo.download(0x2101, 0, b"\x01\x02\x03\x04\x05")


def test_complete_access_and_pdo_assignment(sdo: SdoClient) -> None:
    assign = sdo.upload(0x1C12, 0, complete_access=True)
    count = assign[0]
    assert assign[1] == 0, "subindex 0 is padded to 16 bits"
    pdos = [v for (v,) in struct.iter_unpack("<H", assign[2 : 2 + 2 * count])]
    assert all(0x1600 <= p <= 0x17FF for p in pdos)
    # Rewrite it in PREOP with complete access: the same assignment is accepted.
    sdo.download(0x1C12, 0, assign[: 2 + 2 * count], complete_access=True)
    assert sdo.upload(0x1C12, 0) == bytes([count])


def test_pdo_configuration_rules_in_preop(sdo: SdoClient) -> None:
    with pytest.raises(MailboxError, match="0x06010003 subindex cannot be written"):
        sdo.download(0x1C12, 1, struct.pack("<H", 0x1602))
    sdo.download(0x1C12, 0, b"\x00")
    with pytest.raises(MailboxError, match="0x06090030 value range"):
        sdo.download(0x1C12, 3, struct.pack("<H", 0x1A00))
    # Fill the spare mapping: an input cannot go into an RxPDO, an output can.
    sdo.download(0x1602, 0, b"\x00")
    with pytest.raises(MailboxError, match="0x06040041 object cannot be mapped"):
        sdo.download(0x1602, 1, struct.pack("<I", 0x6010_0110))
    with pytest.raises(MailboxError, match="0x06040041"):
        sdo.download(0x1602, 1, struct.pack("<I", 0x7010_0108))  # wrong bit length
    sdo.download(0x1602, 1, struct.pack("<I", 0x7010_0110))
    sdo.download(0x1602, 0, b"\x01")
    sdo.download(0x1C12, 3, struct.pack("<H", 0x1602))
    with pytest.raises(MailboxError, match="0x06090031 value of parameter written too high"):
        sdo.download(0x1C12, 0, b"\x04")
    sdo.download(0x1C12, 0, b"\x03")
    assign = sdo.upload(0x1C12, 0, complete_access=True)
    assert assign == struct.pack("<BBHHH", 3, 0, 0x1600, 0x1601, 0x1602)


def test_emergency_from_a_refused_state_change(sdo: SdoClient) -> None:
    # SAFEOP without process-data SyncManagers is refused; the slave reports it as an emergency
    # 0xA000 carrying the AL status code, and SDOs keep working in PREOP.
    mailbox = sdo.mailbox
    assert mailbox.dg.fpwr(STATION, 0x0120, struct.pack("<H", 0x04)) == 1
    status, _ = mailbox.dg.fprd(STATION, 0x0130, 2)
    assert status[0] & 0x1F == 0x12, "PREOP with the error flag"
    code, _ = mailbox.dg.fprd(STATION, 0x0134, 2)
    assert sdo.upload(0x1018, 1)
    emergencies = sdo.poll_emergencies()
    assert [e.error_code for e in emergencies] == [0xA000]
    assert emergencies[0].data[:2] == code
    assert "transition PREOP to SAFEOP failed" in emergencies[0].text


def test_sdo_information(sdo: SdoClient) -> None:
    listing = sdo.object_list()
    assert 0x1000 in listing and 0x1C12 in listing and 0x2100 in listing
    assert listing == sorted(listing)
    desc = sdo.object_description(0x1008)
    assert desc.name == "Device name" and desc.object_code == 7
    ed = sdo.entry_description(0x2101, 0)
    assert (ed.data_type, ed.bit_length, ed.readable, ed.writable) == (7, 32, False, True)
