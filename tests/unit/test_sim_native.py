"""Smoke test of the Rust simulator core through `ether_ros._native.SimNetwork`: a tiny
hand-made slave spec, frames built by a small helper, and (as root) SOEM talking to it over a
veth pair."""

from __future__ import annotations

import socket
import struct
import time
from typing import Any

import pytest

from ether_ros._native import (
    Clear,
    Corrupt,
    Delay,
    DriftStep,
    Drop,
    Link,
    MailboxSpec,
    RefuseOp,
    Reset,
    SimNetwork,
    SlaveSpec,
)
from ether_ros._native.protocol import sii_checksum
from ether_ros.errors import InvalidRequest
from ether_ros.testing.netns import VethPair, thread_in_netns
from ether_ros.testing.wait import wait_for

MASTER_MAC = bytes([0x02, 0, 0, 0, 0, 1])
APRD, APWR, FPRD, FPWR, BRD, BWR, LRW = 1, 2, 4, 5, 7, 8, 12
MBX_RX, MBX_TX, OUT_SM, IN_SM = 0x1000, 0x1080, 0x1100, 0x1180
VENDOR, PRODUCT = 0x00000A12, 0x00A986FD


def sii_image(alias: int = 0) -> bytes:
    """Configuration area, identity, standard mailbox, SyncM category, end marker."""
    w = [0] * 0x40
    w[0] = 0x0C80
    w[4] = alias
    w[8], w[9] = VENDOR & 0xFFFF, VENDOR >> 16
    w[10], w[11] = PRODUCT & 0xFFFF, PRODUCT >> 16
    w[0x18], w[0x19], w[0x1A], w[0x1B], w[0x1C] = MBX_RX, 128, MBX_TX, 128, 0x0004
    w[0x3E], w[0x3F] = 0x0001, 0x0001
    b = bytearray(struct.pack("<64H", *w))
    b[14] = sii_checksum(bytes(b[:14]))
    sms = [(MBX_RX, 128, 0x26, 1, 1), (MBX_TX, 128, 0x22, 1, 2)]
    sms += [(OUT_SM, 2, 0x64, 1, 3), (IN_SM, 4, 0x20, 1, 4)]
    cat = b"".join(struct.pack("<HHBBBB", s, n, c, 0, e, t) for s, n, c, e, t in sms)
    b += struct.pack("<HH", 41, len(cat) // 2) + cat
    b += struct.pack("<H", 0xFFFF)
    return bytes(b)


def spec(alias: int = 0, **fields: Any) -> SlaveSpec:
    """Output 0x7000:1 (u16) via 0x1600, input 0x6000:1 (u32) via 0x1A00."""
    u8, u16, u32 = 5, 6, 7
    entries = [
        (0x1000, 0, "Device type", u32, 32, "ro", False, struct.pack("<I", 0x00020192)),
        (0x1C00, 0, "n", u8, 8, "ro", False, b"\x04"),
        *((0x1C00, k, f"sm{k}", u8, 8, "ro", False, bytes([k])) for k in range(1, 5)),
        (0x1600, 0, "n", u8, 8, "rw", False, b"\x01"),
        (0x1600, 1, "e1", u32, 32, "rw", False, struct.pack("<I", 0x70000110)),
        (0x1A00, 0, "n", u8, 8, "rw", False, b"\x01"),
        (0x1A00, 1, "e1", u32, 32, "rw", False, struct.pack("<I", 0x60000120)),
        (0x1C12, 0, "n", u8, 8, "rw", False, b"\x01"),
        (0x1C12, 1, "p1", u16, 16, "rw", False, struct.pack("<H", 0x1600)),
        (0x1C13, 0, "n", u8, 8, "rw", False, b"\x01"),
        (0x1C13, 1, "p1", u16, 16, "rw", False, struct.pack("<H", 0x1A00)),
        (0x6000, 1, "Input", u32, 32, "ro", True, struct.pack("<I", 0x11223344)),
        (0x7000, 1, "Output", u16, 16, "rw", True, b"\x00\x00"),
    ]
    objects = [
        (i, f"obj {i:04X}", 7 if i == 0x1000 else 9) for i in sorted({e[0] for e in entries})
    ]
    base: dict[str, Any] = {
        "name": "tiny",
        "vendor_id": VENDOR,
        "product_code": PRODUCT,
        "revision": 0,
        "sii": sii_image(alias),
        "objects": objects,
        "entries": entries,
        "device": "none",
        "params": {},
        "drift_ppm": 0.0,
        "delay_ns": 800,
        "dc_supported": True,
        "dc_required": False,
        "mailbox": MailboxSpec(rx_offset=MBX_RX, rx_size=128, tx_offset=MBX_TX, tx_size=128),
        "pdram_kib": 8,
    }
    return SlaveSpec(**{**base, **fields})


def frame(cmd: int, adp: int, ado: int, data: bytes) -> bytes:
    """One-datagram EtherCAT frame, padded to 60 bytes."""
    dgram = struct.pack("<BBHHHH", cmd, 0x5A, adp & 0xFFFF, ado, len(data), 0) + data + b"\0\0"
    body = struct.pack("<H", len(dgram) | 0x1000) + dgram
    f = b"\xff" * 6 + MASTER_MAC + b"\x88\xa4" + body
    return f.ljust(60, b"\0")


def xfer(net: SimNetwork, cmd: int, adp: int, ado: int, data: bytes) -> tuple[bytes, int]:
    reply = net.process_frame(frame(cmd, adp, ado, data))
    assert reply is not None
    assert reply[6] == MASTER_MAC[0] | 0x02  # SOURCE_MAC[1] set by every ESC
    n = len(data)
    return reply[26 : 26 + n], struct.unpack_from("<H", reply, 26 + n)[0]


def sm(start: int, length: int, control: int) -> bytes:
    return struct.pack("<HHBBBB", start, length, control, 0, 1, 0)


def fmmu(log: int, length: int, phys: int, kind: int) -> bytes:
    return struct.pack("<IHBBHBBBBH", log, length, 0, 7, phys, 0, kind, 1, 0, 0)


def test_frames_bring_a_slave_to_op_and_exchange_process_data() -> None:
    net = SimNetwork(manual_clock_ns=1_000_000_000)
    assert net.add_slave(spec()) == 0
    assert net.add_slave(spec()) == 1
    _, wkc = xfer(net, BRD, 0, 0x0000, b"\0\0")
    assert wkc == 2
    for pos in range(2):
        _, wkc = xfer(net, APWR, -pos, 0x0010, struct.pack("<H", 0x1001 + pos))
        assert wkc == 1
    st = 0x1002
    assert xfer(net, FPWR, st, 0x0800, sm(MBX_RX, 128, 0x26))[1] == 1
    xfer(net, FPWR, st, 0x0808, sm(MBX_TX, 128, 0x22))
    xfer(net, FPWR, st, 0x0120, b"\x02\x00")
    status, _ = xfer(net, FPRD, st, 0x0130, b"\0" * 6)
    assert struct.unpack("<HHH", status) == (2, 0, 0)
    xfer(net, FPWR, st, 0x0810, sm(OUT_SM, 2, 0x64))
    xfer(net, FPWR, st, 0x0818, sm(IN_SM, 4, 0x20))
    xfer(net, FPWR, st, 0x0600, fmmu(0x10000, 2, OUT_SM, 2))
    xfer(net, FPWR, st, 0x0610, fmmu(0x10002, 4, IN_SM, 1))
    xfer(net, FPWR, st, 0x0120, b"\x04\x00")
    data, wkc = xfer(net, LRW, 0x0000, 0x0001, struct.pack("<H", 0xBEEF) + b"\0" * 4)
    assert wkc == 3
    assert data[2:] == struct.pack("<I", 0x11223344)
    xfer(net, FPWR, st, 0x0120, b"\x08\x00")
    info = net.slave_info(1)
    assert (info["al_state_name"], info["al_status_code"], info["station_address"]) == ("OP", 0, st)
    xfer(net, LRW, 0x0000, 0x0001, struct.pack("<H", 0xBEEF) + b"\0" * 4)
    assert net.od_read(1, 0x7000, 1) == struct.pack("<H", 0xBEEF)
    net.od_write(1, 0x6000, 1, struct.pack("<I", 7))
    data, _ = xfer(net, LRW, 0x0000, 0x0001, b"\0" * 6)
    assert data[2:] == struct.pack("<I", 7)
    # The watchdog (100 ms) expires without outputs.
    net.advance_clock(200_000_000)
    net.poll()
    info = net.slave_info(1)
    assert (info["al_state_name"], info["al_error"], info["al_status_code"]) == (
        "SAFEOP",
        True,
        0x1B,
    )
    assert info["watchdog_expired"]
    stats = net.stats()
    assert stats["commands"]["LRW"] == 3
    assert stats["frames_answered"] == stats["frames_seen"]


def test_faults_and_bad_input_are_reported() -> None:
    net = SimNetwork(seed=7, manual_clock_ns=1)
    net.add_slave(spec())
    net.inject(Drop(rate=1.0, burst=2))
    assert net.process_frame(frame(BRD, 0, 0, b"\0\0")) is None
    net.inject(Clear())
    assert net.process_frame(frame(BRD, 0, 0, b"\0\0")) is not None
    net.inject(Link(up=False))
    assert net.process_frame(frame(BRD, 0, 0, b"\0\0")) is None
    net.inject(Link(up=True))
    net.inject(RefuseOp(slave=0))
    assert net.slave_info(0)["refuse_op"]
    net.inject(DriftStep(slave=0, ppm=25.0))
    assert net.slave_info(0)["dc_drift_ppm"] == 25.0
    assert net.process_frame(b"\x00" * 10) is None
    assert net.process_frame(b"\xff" * 6 + MASTER_MAC + b"\x08\x00" + b"\0" * 46) is None
    # A fault is checked when made, like the engine plan: an unknown keyword, a missing
    # field and a value out of range are named with the type they belong to.
    with pytest.raises(
        TypeError, match=r"Drop.__new__\(\) got an unexpected keyword argument 'speed'"
    ):
        Drop(rate=0.1, speed=3)  # type: ignore[call-arg]
    with pytest.raises(
        TypeError, match=r"Drop.__new__\(\) missing 1 required keyword argument: 'rate'"
    ):
        Drop()  # type: ignore[call-arg]
    with pytest.raises(ValueError, match=r"Drop.rate: 2 is outside 0..=1"):
        Drop(rate=2.0)
    with pytest.raises(ValueError, match=r"Corrupt.bytes: 0 is outside 1..=64"):
        Corrupt(rate=0.1, bytes=0)
    with pytest.raises(ValueError, match=r"Reset.slave: -1 is not a slave position"):
        Reset(slave=-1)
    with pytest.raises(ValueError, match=r"Link.port: needs 'at'"):
        Link(up=False, port=2)
    with pytest.raises(TypeError, match="positional"):
        Delay(3000)  # type: ignore[misc]
    # Each default is the constructor's; a fault is a value (equal when its fields are).
    assert (Drop(rate=0.5).burst, Drop(rate=0.5).outbound, Corrupt(rate=0.5).bytes) == (1, False, 1)
    assert RefuseOp(slave=0) == RefuseOp(slave=0, on=True) != RefuseOp(slave=0, on=False)
    assert repr(Link(up=False, at=2)) == "Link(up=False, at=2, port=None)"
    # What only the network knows is checked when the fault is injected.
    with pytest.raises(InvalidRequest, match="no slave at position 4"):
        net.inject(Reset(slave=4))
    with pytest.raises(TypeError, match=r"inject\(\) takes a fault \(Drop, .*\), not str"):
        net.inject("drop")  # type: ignore[arg-type]
    with pytest.raises(InvalidRequest, match="no slave at position 3"):
        net.slave_info(3)
    # A slave spec is checked when made: a wrong type, an unknown or a missing field is
    # named (with the type it belongs to).
    with pytest.raises(TypeError, match="'delay_ns'"):
        spec(delay_ns="soon")
    with pytest.raises(TypeError, match=r"SlaveSpec.*unexpected keyword argument 'colour'"):
        spec(colour="blue")
    with pytest.raises(TypeError, match=r"SlaveSpec.*missing 1 required keyword argument: 'sii'"):
        SlaveSpec(name="x", vendor_id=1, product_code=2, revision=3)  # type: ignore[call-arg]
    with pytest.raises(ValueError, match=r"SlaveSpec\.pdram_kib: expected int 1\.\.=60"):
        spec(pdram_kib=61)
    with pytest.raises(ValueError, match="toaster"):
        net.add_slave(spec(device="toaster"))
    with pytest.raises(ValueError, match="no object entry 0x1234:0"):
        net.od_read(0, 0x1234, 0)
    with pytest.raises(OSError, match="nosuchif0"):
        net.run_on_interface("nosuchif0")
    assert not net.running


def test_refusals_are_typed_errors_naming_the_field_with_a_code() -> None:
    """Every refusal of the simulator's bindings is an ``InvalidRequest`` (still a ValueError)
    whose ``field`` says what to fix and whose ``code`` says why, as data."""
    net = SimNetwork(seed=3, manual_clock_ns=1)
    net.add_slave(spec())
    cases: list[tuple[Any, str, str]] = [
        (lambda: spec(pdram_kib=61), "SlaveSpec.pdram_kib", InvalidRequest.OUT_OF_RANGE),
        (lambda: spec(esc="z80"), "SlaveSpec.esc", InvalidRequest.BAD_VALUE),
        (
            lambda: spec(entries=[(0x2000, 0, "x", 7, 32, "rx", False, None)]),
            "SlaveSpec.entries",
            InvalidRequest.BAD_VALUE,
        ),
        (lambda: net.add_slave(spec(device="toaster")), "SlaveSpec.device", "refused"),
        (
            lambda: net.add_slave(spec(upstream=(5, 1))),
            "SlaveSpec.upstream",
            InvalidRequest.REFUSED,
        ),
        (lambda: Drop(rate=2), "Drop.rate", InvalidRequest.OUT_OF_RANGE),
        (lambda: Reset(slave=-1), "Reset.slave", InvalidRequest.OUT_OF_RANGE),
        (lambda: Link(up=False, port=2), "Link.port", InvalidRequest.BAD_VALUE),
        (lambda: net.inject(Link(up=False, at=0, port=2)), "Link.port", "not_connected"),
        (lambda: net.inject(Reset(slave=4)), "slave", InvalidRequest.NO_SLAVE),
        (lambda: net.od_read(0, 0x1234, 0), "index", InvalidRequest.NO_ENTRY),
        (lambda: net.od_write(0, 0x1234, 0, b"\0"), "index", InvalidRequest.NO_ENTRY),
        (lambda: net.run_on_interface("lo", link="carrier-pigeon"), "link", "bad_value"),
        (lambda: net.run_on_interface("lo", timing="slow"), "timing", "bad_value"),
        (lambda: net.run_on_interface("lo", threads=65), "threads", "out_of_range"),
    ]
    for make, field, code in cases:
        with pytest.raises(InvalidRequest) as err:
            make()
        assert isinstance(err.value, ValueError)
        assert (err.value.field, err.value.code) == (field, code), str(err.value)
        if field.startswith("SlaveSpec.") and code == InvalidRequest.REFUSED:
            assert str(err.value).startswith("slave 'tiny': "), str(err.value)
            assert "slave 'tiny'" not in str(err.value)[len("slave 'tiny': ") :]
        elif "." in field:
            assert field in str(err.value)
    assert len(net) == 1, "a refused slave is not kept"


@pytest.mark.netns
def test_soem_reads_the_sii_and_reaches_safeop_over_veth(veth_apart: VethPair) -> None:
    # Each end in a namespace of its own: SOEM's socket sees every EtherCAT frame of its
    # namespace until it is bound (ether_ros.netns), and other tests' buses run beside this one.
    veth = veth_apart
    pysoem = pytest.importorskip("pysoem")
    net = SimNetwork()
    net.add_slave(spec(alias=0x0042))
    net.add_slave(spec())
    with thread_in_netns(veth.netns):
        net.run_on_interface(veth.slave)
    try:
        master = pysoem.Master()
        with thread_in_netns(veth.master_netns):
            master.open(veth.master)
        try:
            # The simulator's frame thread may still be starting on a loaded host (SOEM's
            # first broadcast read then gets no answer, config_init -1): scan until it answers.
            wait_for("SOEM to find both slaves", lambda: master.config_init() == 2, timeout=20)
            s0 = master.slaves[0]
            assert (s0.man, s0.id) == (VENDOR, PRODUCT)
            assert master.state_check(pysoem.PREOP_STATE, 200_000) == pysoem.PREOP_STATE
            assert s0.sdo_read(0x1000, 0) == struct.pack("<I", 0x00020192)
            master.config_map()
            assert master.state_check(pysoem.SAFEOP_STATE, 200_000) == pysoem.SAFEOP_STATE
            master.send_processdata()
            assert master.receive_processdata(20_000) == 6
            master.state = pysoem.OP_STATE
            master.write_state()
            deadline = time.monotonic() + 2.0
            while time.monotonic() < deadline:
                master.send_processdata()
                master.receive_processdata(2_000)
                if master.state_check(pysoem.OP_STATE, 1_000) == pysoem.OP_STATE:
                    break
            assert master.read_state() == pysoem.OP_STATE
            assert net.slave_info(0)["alias"] == 0x0042
        finally:
            master.close()
    finally:
        net.stop()
    assert net.stats()["frames_answered"] > 10


@pytest.mark.netns
def test_delayed_answers_keep_their_order_over_veth(veth: VethPair) -> None:
    net = SimNetwork()
    net.add_slave(spec())
    net.run_on_interface(veth.slave)
    # Protocol 0 until bound: opened with the EtherType, the socket would queue EtherCAT frames
    # of every interface (other tests' buses on a busy host) until bind() narrows it.
    sock = socket.socket(socket.AF_PACKET, socket.SOCK_RAW, 0)
    try:
        sock.bind((veth.master, 0x88A4))
        sock.settimeout(2.0)
        net.inject(Delay(us=3000))
        sent = time.monotonic()
        for i in range(20):
            sock.send(frame(BWR, 0, 0x0200, struct.pack("<H", i)))
        got: list[int] = []
        first = 0.0
        while len(got) < 20:
            reply, addr = sock.recvfrom(2048)
            if addr[2] == socket.PACKET_OUTGOING:
                continue  # our own frame, seen on the way out
            first = first or time.monotonic()
            got.append(struct.unpack_from("<H", reply, 26)[0])
        assert got == list(range(20))
        # A lower bound only: scheduling hiccups make answers later, never earlier.
        assert first - sent >= 0.0025
    finally:
        sock.close()
        net.stop()
