"""SDO client and mailbox transport against a fake slave one layer down: the fake implements the
``Datagrams`` protocol on a tiny register model (SM0/SM1 status and the two mailbox buffers) and
answers CoE with a small Python SDO server whose faults (wrong toggle, mailbox errors, emergencies,
silence) can be switched on."""

from __future__ import annotations

import struct
from collections import deque
from dataclasses import dataclass, field

import pytest

from ether_ros._native.protocol import emergency_text
from ether_ros.errors import MailboxError, MailboxErrorReply, MailboxTimeout, SdoAbort
from ether_ros.master.coe import SdoClient
from ether_ros.master.mailbox import Mailbox

RX_OFFSET, RX_SIZE = 0x1000, 128
TX_OFFSET, TX_SIZE = 0x1080, 128
STATION = 0x1001


@dataclass
class FakeEntry:
    value: bytearray
    writable: bool = True
    readable: bool = True
    name: str = "entry"
    data_type: int = 0x0007


@dataclass
class FakeSlave:
    """Datagrams endpoint of one fake slave."""

    entries: dict[tuple[int, int], FakeEntry] = field(default_factory=dict)
    outbox: deque[bytes] = field(default_factory=deque)
    requests: list[bytes] = field(default_factory=list)
    silent: bool = False
    break_toggle: bool = False
    mailbox_error: int | None = None
    write_busy: int = 0  # the next N writes find SM0 full
    lose_reads: int = 0  # the next N read-mailbox reads reach the slave but the answer is lost
    last_sent: bytes = b""
    repeat_ack: int = 0
    last_counter: int | None = None
    transfer: dict[str, object] | None = None

    # ---- Datagrams protocol --------------------------------------------------------------

    def fprd(self, station: int, ado: int, length: int) -> tuple[bytes, int]:
        if station != STATION:
            return bytes(length), 0
        if ado == 0x0805:
            full = self.write_busy > 0
            self.write_busy = max(0, self.write_busy - 1)
            return bytes([0x08 if full else 0]), 1
        if ado == 0x080D:
            return bytes([0x08 if self.outbox else 0]), 1
        if ado == 0x080E:
            return bytes([0x01 | self.repeat_ack]), 1
        if ado == 0x080F:
            return bytes([self.repeat_ack]), 1
        if ado == TX_OFFSET and length == TX_SIZE:
            if not self.outbox:
                return bytes(length), 0  # an empty read mailbox refuses the read
            self.last_sent = self.outbox.popleft()
            if self.lose_reads:
                self.lose_reads -= 1
                return bytes(length), 0
            return self.last_sent.ljust(TX_SIZE, b"\x00"), 1
        return bytes(length), 1

    def fpwr(self, station: int, ado: int, data: bytes) -> int:
        if station == STATION and ado == 0x080E and len(data) == 1:
            if data[0] & 0x02 != self.repeat_ack:
                # Repeat request: the last message goes back into the read mailbox.
                self.repeat_ack = data[0] & 0x02
                self.outbox.appendleft(self.last_sent)
            return 1
        if station != STATION or ado != RX_OFFSET or len(data) != RX_SIZE:
            return 0
        length, _addr, _chan, type_counter = struct.unpack_from("<HHBB", data)
        counter = type_counter >> 4
        expected = 0 if self.last_counter is None else self.last_counter % 7 + 1
        assert counter == expected, "first message 0, then 1..7 cycling"
        self.last_counter = counter
        payload = data[6 : 6 + length]
        self.requests.append(payload)
        if self.mailbox_error is not None:
            self.push(0, struct.pack("<HH", 1, self.mailbox_error))
        elif not self.silent:
            for reply in self.coe(payload):
                self.push(3, reply)
        return 1

    def push(self, mbx_type: int, payload: bytes) -> None:
        self.outbox.append(struct.pack("<HHBB", len(payload), 0, 0, mbx_type | 0x10) + payload)

    def emergency(self, code: int, register: int, data: bytes) -> None:
        self.push(3, struct.pack("<HHB", 1 << 12, code, register) + data)

    # ---- the SDO server model ------------------------------------------------------------

    def coe(self, r: bytes) -> list[bytes]:
        service = r[1] >> 4
        if service == 8:
            return self.info(r)
        cmd = r[2]
        index, sub = struct.unpack_from("<HB", r, 3)
        cs = cmd >> 5
        if cs == 2:  # upload initiate
            entry = self.entries.get((index, sub))
            if entry is None:
                return [abort(index, sub, 0x06020000)]
            data = bytes(entry.value)
            if len(data) <= 4:
                flags = 0x43 | (4 - len(data)) << 2
                return [sdo_frame(3, flags, index, sub, data.ljust(4, b"\x00"))]
            room = RX_SIZE - 6 - 10
            self.transfer = {"data": data, "sent": room, "toggle": 0}
            return [sdo_frame(3, 0x41, index, sub, struct.pack("<I", len(data))) + data[:room]]
        if cs == 3:  # upload segment
            t = self.transfer
            assert t is not None
            data, sent, toggle = t["data"], t["sent"], t["toggle"]
            assert isinstance(data, bytes) and isinstance(sent, int) and isinstance(toggle, int)
            if cmd & 0x10 != toggle:
                return [abort(0, 0, 0x05030000)]
            chunk = data[sent : sent + TX_SIZE - 6 - 3]
            last = sent + len(chunk) == len(data)
            echoed = toggle ^ 0x10 if self.break_toggle else toggle
            unused = 7 - len(chunk) if len(chunk) < 7 else 0
            t.update(sent=sent + len(chunk), toggle=toggle ^ 0x10)
            head = struct.pack("<HB", 3 << 12, echoed | unused << 1 | int(last))
            return [head + chunk.ljust(7, b"\x00")]
        if cs == 1:  # download initiate
            entry = self.entries.get((index, sub))
            if entry is None:
                return [abort(index, sub, 0x06020000)]
            if not entry.writable:
                return [abort(index, sub, 0x06010002)]
            if cmd & 0x02:
                n = 4 - ((cmd >> 2) & 3)
                entry.value[:] = r[6 : 6 + n]
                return [sdo_frame(3, 0x60, index, sub)]
            size = struct.unpack_from("<I", r, 6)[0]
            data = r[10:]
            if len(data) >= size:
                entry.value[:] = data[:size]
            else:
                self.transfer = {"entry": entry, "size": size, "data": bytearray(data), "toggle": 0}
            return [sdo_frame(3, 0x60, index, sub)]
        if cs == 0:  # download segment
            t = self.transfer
            assert t is not None
            buf, toggle = t["data"], t["toggle"]
            assert isinstance(buf, bytearray) and isinstance(toggle, int)
            if cmd & 0x10 != toggle:
                return [abort(0, 0, 0x05030000)]
            body = r[3:]
            if len(body) <= 7:
                body = body[: 7 - ((cmd >> 1) & 7)]
            buf += body
            t["toggle"] = toggle ^ 0x10
            if cmd & 1:
                entry = t["entry"]
                assert isinstance(entry, FakeEntry)
                entry.value[:] = buf
            echoed = toggle ^ 0x10 if self.break_toggle else toggle
            return [struct.pack("<HB", 3 << 12, 0x20 | echoed) + bytes(7)]
        return [abort(index, sub, 0x05040001)]

    def info(self, r: bytes) -> list[bytes]:
        opcode = r[2] & 0x7F
        if opcode == 1:
            indices = sorted({i for i, _ in self.entries})
            body = struct.pack("<H", 1) + b"".join(struct.pack("<H", i) for i in indices)
            return fragments(2, body)
        if opcode == 3:
            (index,) = struct.unpack_from("<H", r, 6)
            subs = [s for i, s in self.entries if i == index]
            if not subs:
                return [info_error(0x06020000)]
            e = self.entries[(index, min(subs))]
            body = struct.pack("<HHBB", index, e.data_type, max(subs), 7) + e.name.encode()
            return fragments(4, body)
        if opcode == 5:
            index, sub = struct.unpack_from("<HB", r, 6)
            e = self.entries.get((index, sub))
            if e is None:
                return [info_error(0x06090011)]
            bits = len(e.value) * 8
            body = struct.pack("<HBBHHH", index, sub, 0, e.data_type, bits, 0x3F)
            return fragments(6, body + e.name.encode())
        return [info_error(0x05040001)]


def sdo_frame(service: int, cmd: int, index: int, sub: int, data: bytes = bytes(4)) -> bytes:
    return struct.pack("<HBHB", service << 12, cmd, index, sub) + data


def abort(index: int, sub: int, code: int) -> bytes:
    return sdo_frame(2, 0x80, index, sub, struct.pack("<I", code))


def info_error(code: int) -> bytes:
    return struct.pack("<HBBHI", 8 << 12, 7, 0, 0, code)


def fragments(opcode: int, body: bytes) -> list[bytes]:
    room = (TX_SIZE - 6 - 6) & ~1
    chunks = [body[i : i + room] for i in range(0, len(body), room)] or [b""]
    out = []
    for k, chunk in enumerate(chunks):
        left = len(chunks) - 1 - k
        out.append(struct.pack("<HBBH", 8 << 12, opcode | (0x80 if left else 0), 0, left) + chunk)
    return out


def make_client(slave: FakeSlave, timeout_s: float = 0.2) -> SdoClient:
    mbx = Mailbox(slave, STATION, "front_left_leg", RX_OFFSET, RX_SIZE, TX_OFFSET, TX_SIZE)
    return SdoClient(mbx, "front_left_leg", timeout_s=timeout_s)


@pytest.fixture
def slave() -> FakeSlave:
    s = FakeSlave()
    s.entries[(0x1000, 0)] = FakeEntry(bytearray(struct.pack("<I", 0x1389)), name="Device type")
    s.entries[(0x2000, 0)] = FakeEntry(bytearray(2), name="Gain", data_type=0x0006)
    s.entries[(0x1008, 0)] = FakeEntry(bytearray(b"Laelaps II leg " * 30), writable=False)
    s.entries[(0x2003, 0)] = FakeEntry(bytearray(400), name="Blob", data_type=0x000A)
    return s


def test_expedited_upload_and_download(slave: FakeSlave) -> None:
    sdo = make_client(slave)
    assert sdo.upload(0x1000, 0) == struct.pack("<I", 0x1389)
    sdo.download(0x2000, 0, b"\x34\x12")
    assert slave.entries[(0x2000, 0)].value == b"\x34\x12"
    # Expedited request: command 0x2B = download initiate, expedited, size given, 2 unused bytes.
    assert slave.requests[-1][2] == 0x2B
    assert sdo.upload(0x2000, 0) == b"\x34\x12"


def test_segmented_upload_and_download(slave: FakeSlave) -> None:
    sdo = make_client(slave)
    assert sdo.upload(0x1008, 0) == b"Laelaps II leg " * 30
    # Upload segment requests alternate the toggle bit, starting with 0.
    toggles = [r[2] & 0x10 for r in slave.requests if r[2] >> 5 == 3]
    assert len(toggles) >= 3
    assert toggles == [(k % 2) * 0x10 for k in range(len(toggles))]
    blob = bytes(range(256)) + bytes(range(144))
    slave.requests.clear()
    sdo.download(0x2003, 0, blob)
    assert slave.entries[(0x2003, 0)].value == blob
    assert all(len(r) <= RX_SIZE - 6 for r in slave.requests)
    assert slave.requests[-1][2] & 0x01, "last segment flagged"
    # A tail shorter than 7 bytes is padded and its size given in bits 1..3.
    slave.requests.clear()
    short = bytes(range(RX_SIZE - 6 - 10 + 3))
    sdo.download(0x2003, 0, short)
    assert slave.entries[(0x2003, 0)].value == short
    assert slave.requests[-1][2] == 0x01 | (4 << 1)


def test_abort_is_raised_with_slave_object_and_text(slave: FakeSlave) -> None:
    sdo = make_client(slave)
    with pytest.raises(SdoAbort) as e:
        sdo.upload(0x6010, 1)
    assert (e.value.slave, e.value.index, e.value.subindex, e.value.code) == (
        "front_left_leg", 0x6010, 1, 0x06020000
    )  # fmt: skip
    assert str(e.value) == (
        "slave 'front_left_leg': SDO upload 0x6010:01 aborted: "
        "0x06020000 object does not exist in the object dictionary"
    )
    with pytest.raises(SdoAbort, match=r"download 0x1008:00 aborted: 0x06010002 attempt") as e:
        sdo.download(0x1008, 0, b"xxxxxxxx")
    assert e.value.code == 0x06010002


def test_toggle_error_from_slave_aborts_the_transfer(slave: FakeSlave) -> None:
    sdo = make_client(slave)
    slave.break_toggle = True
    with pytest.raises(MailboxError, match="did not alternate the toggle bit"):
        sdo.upload(0x1008, 0)
    last = slave.requests[-1]
    assert last[2] == 0x80 and struct.unpack_from("<I", last, 6)[0] == 0x05030000


def test_timeout_names_slave_and_what_was_awaited(slave: FakeSlave) -> None:
    slave.silent = True
    sdo = make_client(slave, timeout_s=0.05)
    with pytest.raises(MailboxTimeout) as e:
        sdo.upload(0x1000, 0)
    assert (e.value.slave, e.value.context, e.value.timeout_s) == (
        "front_left_leg", "SDO upload 0x1000:00", 0.05
    )  # fmt: skip
    assert "slave 'front_left_leg': SDO upload 0x1000:00 failed: timed out" in str(e.value)
    assert "CoE reply in the read mailbox" in str(e.value)


def test_late_reply_of_a_timed_out_request_is_dropped(slave: FakeSlave) -> None:
    slave.silent = True
    sdo = make_client(slave, timeout_s=0.02)
    with pytest.raises(MailboxError, match="timed out"):
        sdo.upload(0x2000, 0)
    # The slave answers late; the next transfer must not take that answer for its own.
    slave.silent = False
    slave.push(3, sdo_frame(3, 0x4B, 0x2000, 0, b"\x07\x00\x00\x00"))
    slave.emergency(0x5000, 0x01, bytes(5))
    assert sdo.upload(0x1000, 0) == struct.pack("<I", 0x1389)
    assert sdo.mailbox.discarded == 1
    assert [e.error_code for e in sdo.emergencies] == [0x5000]


def test_full_write_mailbox_is_waited_for_then_times_out(slave: FakeSlave) -> None:
    sdo = make_client(slave, timeout_s=0.05)
    slave.write_busy = 3
    assert sdo.upload(0x1000, 0) == struct.pack("<I", 0x1389)
    slave.write_busy = 10**9
    with pytest.raises(MailboxError, match="write mailbox to accept a message"):
        sdo.upload(0x1000, 0)


def test_lost_read_mailbox_answer_is_repeated(slave: FakeSlave) -> None:
    sdo = make_client(slave)
    slave.lose_reads = 1
    assert sdo.upload(0x1000, 0) == struct.pack("<I", 0x1389)
    assert sdo.mailbox.repeats == 1
    slave.lose_reads = 2
    assert sdo.upload(0x1008, 0) == b"Laelaps II leg " * 30
    assert sdo.mailbox.repeats == 3


def test_mailbox_error_reply_raises(slave: FakeSlave) -> None:
    slave.mailbox_error = 0x0004
    sdo = make_client(slave)
    with pytest.raises(
        MailboxErrorReply, match="mailbox error 0x0004 the service in the mail"
    ) as e:
        sdo.upload(0x1000, 0)
    assert e.value.code == 0x0004 and e.value.context == "SDO upload 0x1000:00"


def test_emergency_does_not_end_the_wait_and_is_decoded(slave: FakeSlave) -> None:
    sdo = make_client(slave)
    slave.emergency(0x8611, 0x81, b"\x01\x02\x03\x04\x05")
    assert sdo.upload(0x1000, 0) == struct.pack("<I", 0x1389)
    assert len(sdo.emergencies) == 1
    em = sdo.emergencies[0]
    assert (em.error_code, em.error_register, em.data) == (0x8611, 0x81, b"\x01\x02\x03\x04\x05")
    # 0x8611 is CiA 402's "following error"; the client's old copy of the table knew only the
    # class 0x86xx ("positioning control error"). One table now, the exact text wins.
    assert "0x8611 following error" in em.text
    slave.emergency(0xFF01, 0, bytes(5))
    got = sdo.poll_emergencies()
    assert [e.error_code for e in got] == [0x8611, 0xFF01]
    assert not sdo.emergencies


def test_sdo_information(slave: FakeSlave) -> None:
    for i in range(80):  # enough objects for a fragmented list
        slave.entries[(0x3000 + i, 0)] = FakeEntry(bytearray(1), name=f"P{i}")
    sdo = make_client(slave)
    listing = sdo.object_list()
    assert listing == sorted({i for i, _ in slave.entries})
    desc = sdo.object_description(0x2000)
    assert (desc.index, desc.data_type, desc.max_subindex, desc.name) == (0x2000, 6, 0, "Gain")
    assert desc.object_code_name == "VAR"
    ed = sdo.entry_description(0x2003, 0)
    assert (ed.bit_length, ed.name, ed.access_text) == (3200, "Blob", "rw")
    with pytest.raises(SdoAbort, match=r"entry description 0x2003:05 failed: 0x06090011") as e:
        sdo.entry_description(0x2003, 5)
    assert (e.value.index, e.value.subindex, e.value.code) == (0x2003, 5, 0x06090011)
    with pytest.raises(MailboxError, match=r"object description 0x5555 failed: 0x06020000"):
        sdo.object_description(0x5555)


def test_texts() -> None:
    assert SdoAbort(None, 0, 0, 0x08000022).reason.startswith(
        "0x08000022 data cannot be transferred"
    )
    assert SdoAbort(None, 0, 0, 0x12345678).reason == "0x12345678 unknown abort code"
    # One table of emergency codes now (CiA 301 + 402): 0x2310 is "continuous over-current"
    # in CiA 402; the CoE client's own copy used to know only its class ("current error"),
    # while the diagnostics' copy had the exact text.
    assert emergency_text(0x2310) == "continuous over-current"
    assert emergency_text(0x2399) == "current on the device output side"
    assert emergency_text(0xA000).startswith("EtherCAT state machine")


def test_mailbox_rejects_oversized_messages(slave: FakeSlave) -> None:
    mbx = Mailbox(slave, STATION, "front_left_leg", RX_OFFSET, RX_SIZE, TX_OFFSET, TX_SIZE)
    with pytest.raises(MailboxError, match="exceeds the write mailbox"):
        mbx.send(3, bytes(RX_SIZE), 0.1)
    with pytest.raises(MailboxError, match="mailbox too small"):
        Mailbox(slave, STATION, "x", RX_OFFSET, 6, TX_OFFSET, TX_SIZE)
