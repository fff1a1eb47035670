"""The engine (``ether_ros._native.Engine``) against a small ESC-like responder written here:
in-process through ``Engine.open_sim`` and across a real veth pair with a raw-socket responder
thread. The responder is the one faked layer; the engine, its RT thread, the kernel's packet
sockets and the veth pair are real. No assertion depends on timing."""

from __future__ import annotations

import gc
import os
import socket
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

import engine_plans
import ether_ros._native as _native
from ether_ros.errors import FrameTimeout, LinkError
from ether_ros.master.samples import (
    FLAG_ACYCLIC,
    FLAG_LOST,
    FLAG_PANIC,
    FLAG_SEND_ERROR,
    FLAG_UNMATCHED,
    FLAG_WATCHDOG,
    FLAG_WKC_ERROR,
    Samples,
    decode_samples,
)
from ether_ros.testing.netns import VethPair

Engine = _native.Engine
ETHERTYPE = 0x88A4
LRW, FRMW, FPWR = 12, 14, 5
SAFE = b"\xee" * 12
INPUTS = b"\x11\x22\x33\x44"
PACKET_OUTGOING = 4


def datagrams(frame: bytes | bytearray) -> Iterator[tuple[int, int, int, int, int]]:
    """(header offset, command, index, address, length) of each datagram."""
    end = 16 + (int.from_bytes(frame[14:16], "little") & 0x7FF)
    pos = 16
    while pos + 12 <= end:
        length_word = int.from_bytes(frame[pos + 6 : pos + 8], "little")
        length = length_word & 0x7FF
        yield (
            pos,
            frame[pos],
            frame[pos + 1],
            int.from_bytes(frame[pos + 2 : pos + 6], "little"),
            length,
        )
        pos += 10 + length + 2
        if not length_word & 0x8000:
            break


class FakeEsc:
    """Answers frames like two slaves would, just enough for the engine: an LRW over a 12-byte
    image whose outputs are bytes 0..4 and 6..10 gets INPUTS in the other bytes and working
    counter 6; FRMW returns a reference time; any other datagram reads 0xAB and counts 1."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.seen: list[tuple[int, bytes]] = []  # (frame index, LRW data as received)
        self.drop = False
        self.frames = 0

    def process_frame(self, frame: bytes) -> bytes | None:
        with self.lock:
            self.frames += 1
            if self.drop:
                return None
            out = bytearray(frame)
            for pos, cmd, index, _address, length in datagrams(out):
                data = pos + 10
                wkc = data + length
                if cmd == LRW:
                    self.seen.append((index, bytes(out[data : data + length])))
                    out[data + 4 : data + 6] = INPUTS[:2]
                    out[data + 10 : data + 12] = INPUTS[2:]
                    out[wkc : wkc + 2] = (6).to_bytes(2, "little")
                elif cmd == FRMW:
                    out[data : data + 8] = (time.monotonic_ns() + 10**12).to_bytes(8, "little")
                    out[wkc : wkc + 2] = (2).to_bytes(2, "little")
                elif cmd == FPWR:
                    out[wkc : wkc + 2] = (1).to_bytes(2, "little")
                else:
                    out[data:wkc] = b"\xab" * length
                    out[wkc : wkc + 2] = (1).to_bytes(2, "little")
            out[6] |= 0x02  # slaves mark the source address on the way back
            return bytes(out)

    def outputs(self) -> list[bytes]:
        with self.lock:
            return [d[0:4] + d[6:10] for _i, d in self.seen]

    def last(self) -> bytes:
        """The outputs of the last LRW seen (empty before the first)."""
        out = self.outputs()
        return out[-1] if out else b""


class VethResponder:
    """FakeEsc behind a raw socket on the slave end of a veth pair, in a thread."""

    def __init__(self, ifname: str, esc: FakeEsc) -> None:
        self.esc = esc
        # Protocol 0 until bound: nothing from other interfaces gets queued before bind().
        self.sock = socket.socket(socket.AF_PACKET, socket.SOCK_RAW, 0)
        self.sock.bind((ifname, ETHERTYPE))
        self.sock.settimeout(0.05)
        self.extra: list[bytes] = []  # frames to send once, before the next reply
        self.stopped = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self) -> None:
        while not self.stopped.is_set():
            try:
                frame, addr = self.sock.recvfrom(2048)
            except TimeoutError:
                continue
            if addr[2] == PACKET_OUTGOING:
                continue
            reply = self.esc.process_frame(frame)
            try:
                while self.extra:
                    self.sock.send(self.extra.pop())
                if reply is not None:
                    self.sock.send(reply)
            except OSError:
                # A pulled cable (link down) makes the send fail (ENOBUFS, ENETDOWN): that
                # reply is lost, as on a real wire, and the responder goes on for the next.
                continue

    def close(self) -> None:
        self.stopped.set()
        self.thread.join()
        self.sock.close()


def plan(order: str = "send_at_wake", **fields: Any) -> _native.Plan:
    """One frame: the DC datagrams and one LRW of the 12-byte image; ``fields`` are ``Plan``'s
    keywords."""
    base: dict[str, Any] = {
        "order": order,
        "output_ranges": [(0, 4), (6, 4)],
        "safe_image": SAFE,
        "dc": engine_plans.dc("ref_follows_master"),
        "ring_capacity": 100_000,
    }
    datagrams = [
        *engine_plans.dc_datagrams("ref_follows_master"),
        engine_plans.logical("lrw", 0x10000, 12, 0, 6),
    ]
    return engine_plans.plan(datagrams, 12, **{**base, **fields})


def wait_for(cond: Callable[[], bool], what: str) -> None:
    """Poll generously: these tests are about behaviour, never speed."""
    deadline = time.monotonic() + 15
    while not cond():
        assert time.monotonic() < deadline, f"timed out waiting for {what}"
        time.sleep(0.002)


def drain(engine: _native.Engine) -> Samples:
    records, images = engine.drain_samples(1 << 20)
    return decode_samples(records, images, image_len=12)


@pytest.fixture
def sim() -> Iterator[tuple[_native.Engine, FakeEsc]]:
    esc = FakeEsc()
    engine = Engine.open_sim(esc)
    yield engine, esc
    engine.close()


@pytest.fixture
def wire(veth: VethPair) -> Iterator[tuple[_native.Engine, FakeEsc, VethResponder]]:
    esc = FakeEsc()
    responder = VethResponder(veth.slave, esc)
    engine = Engine.open_interface(veth.master)
    yield engine, esc, responder
    engine.close()
    responder.close()


# ----------------------------------------------------------------------------- acyclic


def test_transact_in_process_returns_data_and_wkc(sim: tuple[_native.Engine, FakeEsc]) -> None:
    engine, _esc = sim
    replies = engine.transact([("BRD", 0x0130_0000, 2), (FPWR, 0x0120_1001, b"\x02\x00")])
    assert replies == [(b"\xab\xab", 1), (b"\x02\x00", 1)]


def test_transact_over_veth(wire: tuple[_native.Engine, FakeEsc, VethResponder]) -> None:
    engine, esc, _r = wire
    assert engine.transact([(4, 0x0130_1001, 4)], timeout_us=200_000) == [(b"\xab" * 4, 1)]
    assert esc.frames == 1
    assert "interface" in engine.link


def test_transact_times_out_after_its_retries(sim: tuple[_native.Engine, FakeEsc]) -> None:
    engine, esc = sim
    esc.drop = True
    with pytest.raises(_native.EngineTimeout, match=r"4 attempt\(s\)") as err:
        engine.transact([("BRD", 0, 2)], timeout_us=100, retries=3)
    assert esc.frames == 4
    # One hierarchy: the engine's timeout is a FrameTimeout (a LinkError) carrying its data.
    assert isinstance(err.value, FrameTimeout) and isinstance(err.value, _native.EngineError)
    assert (err.value.commands, err.value.attempts, err.value.timeout_us) == (("BRD",), 4, 100)


def test_bad_datagrams_are_value_errors_naming_the_problem(
    sim: tuple[_native.Engine, FakeEsc],
) -> None:
    engine, _esc = sim
    with pytest.raises(ValueError, match="unknown command 'XYZ'"):
        engine.transact([("XYZ", 0, 2)])
    with pytest.raises(ValueError, match="datagram 0 must be a tuple"):
        engine.transact([[4, 0, 2]])
    with pytest.raises(ValueError, match="does not fit in one frame"):
        engine.transact([("FPRD", 0, 1000), ("FPRD", 0, 1000)])


def test_open_interface_errors_are_link_errors_naming_the_interface() -> None:
    with pytest.raises(LinkError, match="no network interface named 'nosuchif0'"):
        Engine.open_interface("nosuchif0")
    with pytest.raises(ValueError, match="process_frame"):
        Engine.open_sim(object())


# ----------------------------------------------------------------------------- cyclic


@pytest.mark.parametrize("order", ["send_at_wake", "send_then_wait"])
def test_cyclic_exchange_in_process(sim: tuple[_native.Engine, FakeEsc], order: str) -> None:
    engine, esc = sim
    engine.start_cyclic(plan(order))
    assert engine.is_running
    engine.write_outputs(0, b"\x09\x08\x07\x06")
    engine.write_outputs(6, b"\x05\x04\x03\x02")
    wait_for(lambda: esc.last() == b"\x09\x08\x07\x06\x05\x04\x03\x02", "outputs on the wire")
    expect = b"\x09\x08\x07\x06\x11\x22\x05\x04\x03\x02\x33\x44"
    wait_for(lambda: engine.read_inputs() == expect, "inputs in the image")
    assert engine.outputs()[0:4] == b"\x09\x08\x07\x06"
    # Acyclic datagrams still work: the RT thread sends them after the cyclic frame.
    assert engine.transact([("FPRD", 0x0130_1001, 2)], timeout_us=100_000) == [(b"\xab\xab", 1)]
    engine.stop_cyclic()
    assert not engine.is_running
    s = drain(engine)
    assert len(s) >= 3
    assert (s.records["cycle"][1:] == s.records["cycle"][:-1] + 1).all()
    good = s.records[(s.records["flags"] & FLAG_LOST) == 0]
    assert (good["wkc"][1:] == 6).all()
    assert not (s.records["flags"] & FLAG_WKC_ERROR).any()
    assert (s.records["flags"] & FLAG_ACYCLIC).any()
    assert bytes(s.images[-1]) == expect
    stats = engine.stats()
    assert stats["cycles"] == len(s)
    assert stats["acyclic_frames"] >= 1
    for name in ("wake_latency", "exec", "period", "rtt", "send"):
        h = stats[name]
        assert h["count"] > 0 and h["min"] <= h["p50"] <= h["p99"] <= h["p999"] <= h["max"]
    engine.reset_stats()
    assert engine.stats()["cycles"] == 0


def test_writes_outside_the_output_ranges_are_refused(sim: tuple[_native.Engine, FakeEsc]) -> None:
    engine, _esc = sim
    with pytest.raises(LinkError, match="start_cyclic"):
        engine.write_outputs(0, b"\x01")
    engine.start_cyclic(plan())
    with pytest.raises(ValueError, match=r"\[\(0, 4\), \(6, 4\)\]"):
        engine.write_outputs(3, b"\x00\x00")
    with pytest.raises(ValueError, match="offset 10"):
        engine.write_outputs(10, b"\x00")
    with pytest.raises(LinkError, match="already running"):
        engine.start_cyclic(plan())


@pytest.mark.parametrize(
    ("make", "error", "message"),
    [
        (lambda: plan(order="sideways"), ValueError, 'Plan.order: "sideways" is not one of'),
        (
            lambda: plan(safe_image=b"\x00"),
            ValueError,
            "safe_image is 1 bytes long but image_len is 12",
        ),
        (lambda: plan(cycle_ns="fast"), TypeError, "cycle_ns"),
        (
            lambda: _native.LogicalDatagram(kind="lrw", address=0),
            TypeError,
            r"LogicalDatagram.*missing .*'length'",
        ),
        (lambda: plan(output_ranges=[(10, 4)]), ValueError, r"output_ranges\[0\]"),
        (
            lambda: plan(dc=engine_plans.dc("off")),
            ValueError,
            "dc_write_ref but dc.mode is not ref_follows_master",
        ),
        (
            lambda: engine_plans.rt(policy="fifo", priority=0),
            ValueError,
            r"RtSettings\.priority: 0 is outside 1\.\.=99",
        ),
        (
            lambda: _native.RtSettings(policy="fifo", priority=80),  # type: ignore[call-arg]
            TypeError,
            r"RtSettings.*missing .*'cpu', 'runtime_ns'",
        ),
        # A misspelt or unknown key is refused by name, never taken for an absent one.
        (lambda: plan(watchdog=5), TypeError, r"Plan.*unexpected keyword argument 'watchdog'"),
        (
            lambda: _native.DcSettings(  # type: ignore[call-arg]
                mode="ref_follows_master", time_offset_ns=0, sync0_shift=5
            ),
            TypeError,
            r"DcSettings.*unexpected keyword argument 'sync0_shift'",
        ),
        (
            lambda: engine_plans.frame([engine_plans.logical("lrw", 0, 4, 0, 1)], every=0),
            ValueError,
            r"Frame\.every: 0 is outside",
        ),
        (
            lambda: engine_plans.frame([{"kind": "lrw"}]),  # type: ignore[list-item]
            TypeError,
            r"Frame\.datagrams\[0\]: expected a LogicalDatagram or a DcDatagram, got dict",
        ),
    ],
)
def test_bad_plans_name_the_field(
    make: Callable[[], object], error: type[Exception], message: str
) -> None:
    with pytest.raises(error, match=message):
        make()


def test_plans_are_frozen() -> None:
    p = plan()
    with pytest.raises(AttributeError):
        p.cycle_ns = 5  # type: ignore[misc]
    assert p.frames[0].datagrams[2].kind == "lrw" and p.dc.mode == "ref_follows_master"


def _thread_named(name: str) -> str | None:
    for tid in os.listdir("/proc/self/task"):
        try:
            if Path(f"/proc/self/task/{tid}/comm").read_text().strip() == name:
                return tid
        except FileNotFoundError:
            continue
    return None


def test_rt_thread_runs_sched_fifo_pinned_with_locked_memory(
    wire: tuple[_native.Engine, FakeEsc, VethResponder],
) -> None:
    engine, esc, _r = wire
    rt = engine_plans.rt(policy="fifo", priority=20, cpu=0, lock_memory=True)
    engine.start_cyclic(plan("send_then_wait", rt=rt))
    tid = _thread_named("ether_ros-rt")
    assert tid is not None
    stat = Path(f"/proc/self/task/{tid}/stat").read_text()
    fields = stat[stat.rindex(")") + 2 :].split()
    assert int(fields[38]) == 1  # policy (field 41 of stat): SCHED_FIFO
    assert int(fields[37]) == 20  # rt_priority (field 40)
    status = Path(f"/proc/self/task/{tid}/status").read_text()
    assert "Cpus_allowed_list:\t0\n" in status
    assert "VmLck:\t       0 kB" not in Path("/proc/self/status").read_text()
    wait_for(lambda: len(esc.outputs()) > 5, "cyclic frames over veth")
    engine.stop_cyclic()
    assert _thread_named("ether_ros-rt") is None


def test_sched_deadline_runs_or_is_refused_clearly(sim: tuple[_native.Engine, FakeEsc]) -> None:
    engine, _esc = sim
    rt = engine_plans.rt(policy="deadline", runtime_ns=200_000)
    try:
        engine.start_cyclic(plan(rt=rt))
    except _native.EngineError as e:
        assert "SCHED_DEADLINE" in str(e)
        return
    tid = _thread_named("ether_ros-rt")
    assert tid is not None
    stat = Path(f"/proc/self/task/{tid}/stat").read_text()
    assert int(stat[stat.rindex(")") + 2 :].split()[38]) == 6  # SCHED_DEADLINE
    engine.stop_cyclic()


def test_panic_reaches_the_wire_from_the_next_frame(
    wire: tuple[_native.Engine, FakeEsc, VethResponder],
) -> None:
    engine, esc, _r = wire
    engine.start_cyclic(plan())
    engine.write_outputs(0, b"\x01\x02\x03\x04")
    wait_for(lambda: esc.last()[:4] == b"\x01\x02\x03\x04", "live outputs")
    drain(engine)
    t_call = Engine.now_ns()
    engine.panic()
    t_returned = Engine.now_ns()
    assert engine.is_panicked
    wait_for(lambda: esc.last() == SAFE[:8], "safe outputs")
    time.sleep(0.01)
    t_clear = Engine.now_ns()
    # A write while panicked is voided by the clear (it does not restart, docs/engine.md
    # "Safety"); a command after it goes live.
    engine.write_outputs(0, b"\x06\x06\x06\x06")
    engine.clear_panic()
    assert engine.outputs()[:4] == SAFE[:4]
    engine.write_outputs(0, b"\x05\x05\x05\x05")
    wait_for(lambda: esc.last()[:4] == b"\x05\x05\x05\x05", "live outputs again")
    engine.stop_cyclic()
    r = drain(engine).records
    panicked = (r["flags"] & FLAG_PANIC) != 0
    # Every cycle that woke after panic() returned, until clear_panic(), sent the safe image;
    # of the cycles that woke after the call began, only the first (in progress) may not have.
    assert panicked[(r["t_wake_ns"] > t_returned) & (r["t_wake_ns"] < t_clear)].all()
    first = r[(r["t_wake_ns"] > t_call) & panicked][0]
    assert int(first["cycle"]) - int(r[r["t_wake_ns"] > t_call][0]["cycle"]) <= 1
    # And that frame really carried the safe image to the slaves.
    index = 0x80 | (int(first["cycle"]) & 0x7F)
    sent = {i: d for i, d in esc.seen}
    assert sent[index][0:4] + sent[index][6:10] == SAFE[:8]
    assert engine.stats()["panics"] == 1


def test_watchdog_sends_safe_outputs_when_commands_stop(
    sim: tuple[_native.Engine, FakeEsc],
) -> None:
    engine, esc = sim
    engine.start_cyclic(plan("send_then_wait", watchdog_ns=30_000_000))
    engine.write_outputs(0, b"\x01\x01\x01\x01")
    wait_for(lambda: esc.last() == SAFE[:8], "watchdog safe image")
    assert engine.stats()["watchdog_trips"] >= 1
    engine.write_outputs(0, b"\x07\x07\x07\x07")
    wait_for(lambda: esc.last()[:4] == b"\x07\x07\x07\x07", "outputs after a new command")
    engine.stop_cyclic()
    assert (drain(engine).records["flags"] & FLAG_WATCHDOG).any()


def test_foreign_and_malformed_frames_are_counted_and_ignored(
    wire: tuple[_native.Engine, FakeEsc, VethResponder],
) -> None:
    engine, esc, responder = wire
    engine.start_cyclic(plan())
    engine.write_outputs(0, b"\x03\x03\x03\x03")
    wait_for(lambda: len(esc.outputs()) > 3, "cyclic frames")
    eth = b"\xff" * 6 + b"\x02\x00\x00\x00\x00\x99" + ETHERTYPE.to_bytes(2, "big")
    junk = [
        eth + b"\xff\x17" + bytes(50),  # header claims more datagrams than the frame holds
        eth + (0x100C).to_bytes(2, "little") + bytes([LRW, 0x05]) + bytes(50),  # foreign index
        eth + b"\x00\x10" + bytes(4),  # empty and short
    ]
    for _round in range(5):
        responder.extra.extend(junk)
        wait_for(lambda: not responder.extra, "junk sent")
    wait_for(lambda: engine.stats()["unmatched_frames"] >= 10, "junk counted")
    wait_for(lambda: engine.read_inputs()[4:6] == INPUTS[:2], "exchange continues")
    engine.stop_cyclic()
    s = drain(engine)
    assert (s.records["flags"] & FLAG_UNMATCHED).any()
    assert engine.stats()["wkc_errors"] == 0


def test_pulled_cable_is_counted_and_the_exchange_resumes(
    veth: VethPair, wire: tuple[_native.Engine, FakeEsc, VethResponder]
) -> None:
    engine, esc, _r = wire
    engine.start_cyclic(plan())
    engine.write_outputs(0, b"\x04\x04\x04\x04")
    wait_for(lambda: esc.last()[:4] == b"\x04\x04\x04\x04", "outputs on the wire")
    veth.set_link(False)
    wait_for(lambda: engine.stats()["send_errors"] + engine.stats()["lost_frames"] >= 5, "errors")
    veth.set_link(True)
    seen = len(esc.outputs())
    wait_for(lambda: len(esc.outputs()) > seen + 3, "frames after the cable is back")
    assert engine.is_running
    engine.stop_cyclic()
    assert (drain(engine).records["flags"] & (FLAG_LOST | FLAG_SEND_ERROR)).any()


def test_lost_frames_are_counted_per_cycle(sim: tuple[_native.Engine, FakeEsc]) -> None:
    engine, esc = sim
    engine.start_cyclic(plan())
    wait_for(lambda: engine.stats()["cycles"] > 3, "cycles")
    esc.drop = True
    wait_for(lambda: engine.stats()["lost_frames"] >= 3, "lost frames")
    esc.drop = False
    engine.stop_cyclic()
    assert (drain(engine).records["flags"] & FLAG_LOST).any()


def test_full_ring_drops_new_samples_and_counts_them(sim: tuple[_native.Engine, FakeEsc]) -> None:
    engine, _esc = sim
    engine.start_cyclic(plan(ring_capacity=4))
    wait_for(lambda: engine.stats()["samples_dropped"] >= 2, "dropped samples")
    engine.stop_cyclic()
    s = drain(engine)
    assert len(s) == 4
    assert list(s.records["cycle"]) == [0, 1, 2, 3]  # the oldest are kept, the newest dropped


def test_dropping_a_running_engine_stops_its_thread() -> None:
    # The Python responder needs the GIL in the RT thread: dropping the engine must not hold it
    # while joining (that would deadlock).
    esc = FakeEsc()
    engine = Engine.open_sim(esc)
    engine.start_cyclic(plan())
    wait_for(lambda: len(esc.outputs()) > 2, "cycles")
    del engine
    gc.collect()
    assert _thread_named("ether_ros-rt") is None


def _fds() -> int:
    return len(os.listdir("/proc/self/fd"))


def _engine_threads() -> int:
    """The engine's RT threads (ether_ros-rt) still in this process. Counting every thread of
    the pytest process would also count threads other tests left winding down (rclpy
    executors, responders, command receivers) on a loaded host. A thread that has been joined
    can still be listed for a moment: the kernel wakes the joiner when the thread's tid is
    cleared, a little before it removes the task; so the count is taken once it stops falling,
    for up to 2 s."""

    def count() -> int:
        n = 0
        for tid in os.listdir("/proc/self/task"):
            try:
                if Path(f"/proc/self/task/{tid}/comm").read_text().strip() == "ether_ros-rt":
                    n += 1
            except FileNotFoundError:
                continue
        return n

    deadline = time.monotonic() + 2.0
    n = count()
    while n and time.monotonic() < deadline:
        time.sleep(0.01)
        n = count()
    return n


def test_start_stop_and_open_close_leak_nothing(veth: VethPair) -> None:
    esc = FakeEsc()
    responder = VethResponder(veth.slave, esc)
    try:
        engine = Engine.open_interface(veth.master)
        engine.start_cyclic(plan(cycle_ns=200_000))
        engine.stop_cyclic()
        fds = _fds()
        assert _engine_threads() == 0, "stop_cyclic left the RT thread running"
        for i in range(50):
            engine.start_cyclic(plan(cycle_ns=200_000))
            if i % 10 == 0:
                engine.transact([("BRD", 0, 2)], timeout_us=500_000)
            engine.stop_cyclic()
            engine.drain_samples()
        assert (_fds(), _engine_threads()) == (fds, 0)
        engine.close()
        assert _fds() == fds - 1  # the raw socket
        with pytest.raises(LinkError, match="closed"):
            engine.transact([("BRD", 0, 2)])
        for _ in range(20):
            Engine.open_interface(veth.master).close()
        assert _fds() == fds - 1
    finally:
        responder.close()
