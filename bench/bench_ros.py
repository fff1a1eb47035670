"""The ROS 2 interface: how long a command published on ROS takes to reach the wire, where that
time goes, and what publishing every cycle costs the real-time loop.

Setup: `RosRig` — the simulator (`ether-ros sim config/laelaps.yaml`, 4 Laelaps II legs) and the
node (`ether-ros run`, 400 µs cycle, SCHED_FIFO) in their own processes on a veth pair, with a ROS
domain of their own (localhost discovery).

1. Topic → wire. A command sender (a worker process, `bench/ros_floor.py publish`, so that the
   benchmark's own ROS client and sniffer share neither its interpreter nor its GIL) publishes
   `WriteVariable` (front_left_leg `Kp100_hip` = a new value, unique within the run) on
   `pdo_listener` in two patterns: sparse (one value every 20 ms) and a command stream (a new
   value every 1 ms, as a locomotion controller sends), each send moved by a random part of
   one cycle so that its phase to the master's cycle is uniform. For every value it notes
   `time.time_ns()` before building the message, right before `publish()` and right after it
   returns. A raw socket on the
   simulator's end of the veth pair notes the kernel timestamp (SO_TIMESTAMPNS: CLOCK_REALTIME,
   the clock of `time.time_ns()`) of every frame whose LRW data carries a new value there; each
   value is matched to the first frame carrying it or a later value (a value replaced by the next
   one within the same cycle never shows; the frame that carries its successor is the first one
   sent after it was applied). Measured with the node publishing as configured (`pdo_raw` every
   cycle) and with its publishing turned off. The `write_variables` service round trip too.
2. The DDS floor, in the same run while the rig is up (the same load on the machine): the same
   sender publishes the same patterns, in another ROS domain, to a minimal subscriber
   (`ros_floor.py subscribe`: a low-level rclpy wait set) that notes `time.time_ns()` right after
   `rcl_wait` returns and keeps the middleware's `received_timestamp` of each sample.
   publish() returned → received is the middleware's own delivery, with no node and no
   EtherCAT; the node's publish() returned → wire minus that floor is the node's own share
   plus the wait for the next frame.
3. Publishing at 2.5 kHz vs not: two runs of the node, one publishing `pdo_raw` every cycle
   (plus decoded values every 10th), one publishing nothing (decimations 10^6); the engine's
   wake-up latency and period (its own histograms, from `diagnostics`) and the node process's CPU
   use in each. The RT thread never waits for Python, so the latency should not move beyond the
   VM's run-to-run noise; the CPU use is what ROS costs.
"""

from __future__ import annotations

import contextlib
import itertools
import json
import os
import queue
import socket
import struct
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import IO, NamedTuple

from baseline import ToolError
from report import BenchSkipped, Report, us

REPO = Path(__file__).resolve().parent.parent
CONFIG = REPO / "config" / "laelaps.yaml"
WORKER = Path(__file__).resolve().parent / "ros_floor.py"
SLAVE = "front_left_leg"
VARIABLE = "Kp100_hip"
# (name, description, seconds between values, sender: "python" = rclpy publish() of a message
# built at that moment by a normal thread; "controller" = a SCHED_FIFO sender publishing
# messages serialized beforehand, as a real-time controller node would)
PATTERNS: tuple[tuple[str, str, float, str], ...] = (
    ("sparse", "one value every 20 ms", 0.020, "python"),
    ("stream", "a new value every 1 ms", 0.001, "python"),
    ("controller", "a new value every 1 ms from a SCHED_FIFO 60 sender, serialized in advance",
     0.001, "controller"),
)  # fmt: skip
VARIANTS = (("publishing", "node publishing at 2.5 kHz"), ("quiet", "node not publishing"))
# The target for a command: on the wire within one cycle + this.
TARGET_MARGIN_NS = 200_000
FLOOR_DOMAIN_OFFSET = 5  # RosRig's domain is offset 0, _one_run's 3 and 4
PYTHON_DOMAIN_OFFSET = 6  # the node with --python-commands


def _percentile(values: list[float], q: float) -> float:
    s = sorted(values)
    return s[min(len(s) - 1, int(q * (len(s) - 1) + 0.5))] if s else float("nan")


def _variable_offset() -> int:
    """Byte offset of SLAVE.VARIABLE in the output image (outputs of the slaves in bus order)."""
    from ether_ros.config import load_bus_config

    cfg = load_bus_config(CONFIG)
    offset = 0
    for s in sorted(cfg.slaves, key=lambda s: s.position or 0):
        if s.name == SLAVE:
            return offset + s.layout.variable(VARIABLE).byte_offset
        offset += s.layout.output_bytes
    raise KeyError(SLAVE)


def _cycle_ns() -> int:
    from ether_ros.config import load_bus_config

    return int(load_bus_config(CONFIG).bus.cycle_us) * 1000


def _cpu_seconds(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


# ---------------------------------------------------------------------------------------------
# Worker processes (bench/ros_floor.py)


class Sent(NamedTuple):
    """One published value and the sender's three stamps (time.time_ns())."""

    seq: int  # the sender's running number (the value is derived from it)
    value: int
    t_construct: int  # before building the message
    t_publish: int  # right before publish()
    t_returned: int  # right after publish() returned


class Worker:
    """A ``ros_floor.py`` process in ROS domain ``domain_id``, spoken to by lines on its
    stdin/stdout (its stderr goes to a temporary file, shown when it fails)."""

    def __init__(self, args: list[str], domain_id: int, what: str) -> None:
        self.what = what
        env = dict(os.environ)
        env["ROS_DOMAIN_ID"] = str(domain_id)
        env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
        env["PYTHONUNBUFFERED"] = "1"
        # Lives as long as the worker; closed in close().
        self._stderr: IO[str] = tempfile.TemporaryFile("w+")  # noqa: SIM115
        self.proc = subprocess.Popen(
            [sys.executable, str(WORKER), *args],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=self._stderr,
            text=True,
            env=env,
        )
        self._lines: queue.Queue[str] = queue.Queue()
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            self._lines.put(line)
        self._lines.put("")  # end of output

    def line(self, timeout: float) -> str:
        try:
            line = self._lines.get(timeout=timeout)
        except queue.Empty:
            raise ToolError(f"{self.what} did not answer within {timeout:g} s") from None
        if not line:
            self.proc.wait(5)
            self._stderr.seek(0)
            detail = self._stderr.read().strip()[-800:]
            raise ToolError(f"{self.what} exited ({self.proc.returncode}): {detail}")
        return line

    def expect_ready(self, timeout: float = 60.0) -> None:
        line = self.line(timeout)
        if line.strip() != "ready":
            raise ToolError(f"{self.what} did not start: {line.strip()[:200]!r}")

    def send(self, text: str) -> None:
        assert self.proc.stdin is not None
        self.proc.stdin.write(text + "\n")
        self.proc.stdin.flush()

    def close(self) -> None:
        if self.proc.stdin is not None and not self.proc.stdin.closed:
            with contextlib.suppress(OSError):  # the worker may be gone already
                self.proc.stdin.close()
        try:
            self.proc.wait(10)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
        self._stderr.close()


class CommandSender:
    """The sender process: publishes the patterns, returns the stamps of every value. Sequence
    numbers (and so values) go on rising across calls: unique within one sender."""

    def __init__(self, domain_id: int, args: list[str] | None = None) -> None:
        args = args or ["publish", SLAVE, VARIABLE]
        self.worker = Worker(args, domain_id, "the command sender")
        self.next_seq = 0
        try:
            self.worker.expect_ready()
        except BaseException:
            self.worker.close()
            raise

    def send(self, gap_s: float, count: int, dither_s: float, sender: str) -> list[Sent]:
        self.worker.send(f"{gap_s} {count} {self.next_seq} {dither_s} {sender}")
        rows = json.loads(self.worker.line(timeout=count * gap_s + 30))
        self.next_seq += count
        return [Sent(*row) for row in rows]

    def end(self) -> None:
        """Tell a floor subscriber to stop and report."""
        self.worker.send("end")
        self.worker.line(timeout=10)

    def close(self) -> None:
        self.worker.close()


# ---------------------------------------------------------------------------------------------
# The wire


ETH_P_ALL = 0x0003
LRW = 0x0C
SO_TIMESTAMPNS = 35
SCM_TIMESTAMPNS = SO_TIMESTAMPNS
SOL_PACKET = 263
PACKET_STATISTICS = 6


class WireSniffer:
    """Watches the frames the master sends, as they arrive at the simulator's end of the veth
    pair, and notes (kernel timestamp, value) whenever the value at ``offset`` of the process
    image in the LRW data changes (one LRW covers the whole image here). Only the kernel's
    timestamps count, so this thread's own delays do not matter."""

    def __init__(self, interface: str, offset: int, fmt: str = "<h") -> None:
        self.offset = offset
        self.fmt = fmt  # the value's struct format (int16 by default)
        self.changes: list[tuple[int, int]] = []
        self.frames = 0
        self.dropped = 0
        # time.time_ns() at reading minus the kernel stamp: never negative when both are the
        # same clock (CLOCK_REALTIME); checked, not assumed.
        self.min_read_delay_ns: int | None = None
        # The master's socket bypasses the qdisc (and with it the taps on its own end), so the
        # frames are taken where they arrive: the simulator's end of the pair.
        # Protocol 0 until bound: nothing from other interfaces is queued before bind().
        self._sock = socket.socket(socket.AF_PACKET, socket.SOCK_RAW, 0)
        self._sock.setsockopt(socket.SOL_SOCKET, SO_TIMESTAMPNS, 1)
        self._sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4 << 20)
        self._sock.bind((interface, ETH_P_ALL))
        self._sock.settimeout(0.2)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def close(self) -> None:
        if self._stop.is_set():
            return
        self._stop.set()
        self._thread.join(2)
        self.dropped = self._dropped()
        self._sock.close()

    def _dropped(self) -> int:
        """Frames the kernel dropped because this socket's buffer was full (since the last
        call): a dropped frame could hide a value's first frame, so it is counted."""
        _received, dropped = struct.unpack(
            "II", self._sock.getsockopt(SOL_PACKET, PACKET_STATISTICS, 8)
        )
        return int(dropped)

    def _run(self) -> None:
        last: int | None = None
        while not self._stop.is_set():
            try:
                frame, ancillary, _flags, address = self._sock.recvmsg(2048, 64)
            except TimeoutError:
                continue
            except OSError:
                return
            now = time.time_ns()
            if address[2] == socket.PACKET_OUTGOING or frame[12:14] != b"\x88\xa4":
                continue
            self.frames += 1
            value = self._lrw_value(frame)
            if value is None or value == last:
                continue
            last = value
            for level, kind, data in ancillary:
                if level == socket.SOL_SOCKET and kind == SCM_TIMESTAMPNS:
                    sec, nsec = struct.unpack("qq", data[:16])
                    stamp = sec * 1_000_000_000 + nsec
                    self.changes.append((stamp, value))
                    delay = now - stamp
                    if self.min_read_delay_ns is None or delay < self.min_read_delay_ns:
                        self.min_read_delay_ns = delay

    def _lrw_value(self, frame: bytes) -> int | None:
        pos = 16  # Ethernet header (14) + EtherCAT header (2)
        while pos + 10 <= len(frame):
            cmd = frame[pos]
            length = struct.unpack_from("<H", frame, pos + 6)[0]
            more, length = length & 0x8000, length & 0x07FF
            data = pos + 10
            if cmd == LRW and self.offset + struct.calcsize(self.fmt) <= length:
                return int(struct.unpack_from(self.fmt, frame, data + self.offset)[0])
            if not more:
                return None
            pos = data + length + 2
        return None


def first_frames(sent: list[Sent], changes: list[tuple[int, int]]) -> dict[int, tuple[int, bool]]:
    """Sequence number -> (kernel stamp of the first frame carrying its value or a later one,
    whether it was a later one), from the sniffer's value changes. The node applies commands in
    order, so when a frame first carries command ``j``, every earlier command not seen yet was
    applied after the previous frame and replaced before this one: this frame is the first one
    sent after it was applied. A frame earlier than the command's publish() (the variable held
    that value already) is not its frame."""
    order = sorted(s.seq for s in sent)
    seq_of = {s.value: s.seq for s in sent}
    published = {s.seq: s.t_publish for s in sent}
    out: dict[int, tuple[int, bool]] = {}
    pos = 0
    for stamp, value in changes:
        j = seq_of.get(value)
        if j is None or stamp < published[j]:
            continue
        while pos < len(order) and order[pos] <= j:
            out[order[pos]] = (stamp, order[pos] != j)
            pos += 1
    return out


# ---------------------------------------------------------------------------------------------
# Measurement


class Timings:
    """The stamps of one (variant, pattern) measurement, as latencies in ns. (A plain class:
    bench/run.py loads this module without registering it, which dataclasses need.)"""

    def __init__(self, sent: int) -> None:
        self.sent = sent
        self.call_to_end: list[float] = []  # right before publish() -> wire / woken
        self.returned_to_end: list[float] = []  # publish() returned -> wire / woken
        self.publish: list[float] = []  # publish() duration
        self.construct: list[float] = []  # building the message
        self.take: list[float] = []  # floor only: take_message in Python
        self.returned_to_received: list[float] = []  # floor only: -> DDS had the sample
        self.received_to_woken: list[float] = []  # floor only: the subscriber's wake-up
        self.interval: list[float] = []  # between two publish() calls: the sender's schedule
        self.missed = 0
        self.superseded = 0


def _sender_side(sent: list[Sent]) -> Timings:
    p = Timings(len(sent))
    for s in sent:
        p.publish.append(s.t_returned - s.t_publish)
        p.construct.append(s.t_publish - s.t_construct)
    p.interval = [b.t_publish - a.t_publish for a, b in itertools.pairwise(sent)]
    return p


def _wire_path(sent: list[Sent], frames: dict[int, tuple[int, bool]]) -> Timings:
    p = _sender_side(sent)
    for s in sent:
        if s.seq not in frames:
            p.missed += 1
            continue
        stamp, superseded = frames[s.seq]
        p.superseded += superseded
        p.call_to_end.append(stamp - s.t_publish)
        p.returned_to_end.append(stamp - s.t_returned)
    return p


def _floor_path(sent: list[Sent], woken: dict[int, list[int]]) -> Timings:
    p = _sender_side(sent)
    for s in sent:
        if s.seq not in woken:
            p.missed += 1
            continue
        t_woken, t_taken, t_received = woken[s.seq]
        p.call_to_end.append(t_woken - s.t_publish)
        p.returned_to_end.append(t_woken - s.t_returned)
        p.take.append(t_taken - t_woken)
        if t_received:  # 0: the middleware does not stamp reception
            p.returned_to_received.append(t_received - s.t_returned)
            p.received_to_woken.append(t_woken - t_received)
    return p


def _mean(values: list[float]) -> float:
    """The mean without the slowest 1 % (this VM stalls for milliseconds now and then; one
    stall in one sample set would otherwise move a whole column of the breakdown)."""
    if not values:
        return float("nan")
    kept = sorted(values)[: max(1, len(values) - len(values) // 100)]
    return sum(kept) / len(kept)


def _tenths(values: list[float]) -> tuple[float, float]:
    """p50 of the first and of the last tenth of ``values`` (in sending order)."""
    n = max(1, len(values) // 10)
    return _percentile(values[:n], 0.5), _percentile(values[-n:], 0.5)


def _cell(values: list[float]) -> str:
    if not values:
        return "-"
    return f"{us(_percentile(values, 0.5))} / {us(_percentile(values, 0.99))} / {us(max(values))}"


def _record(report: Report, key: str, values: list[float]) -> None:
    if values:
        report.value(f"{key}_p50_ns", _percentile(values, 0.5))
        report.value(f"{key}_p99_ns", _percentile(values, 0.99))
        report.value(f"{key}_max_ns", max(values))


def _measure(samples: int) -> tuple[dict[tuple[str, str], Timings], dict[tuple[str, str], Timings],
                                    list[float], WireSniffer]:  # fmt: skip
    """Node paths and floor paths by (variant, pattern), the service round trips and the
    (closed) sniffer, for its checks."""
    from ether_ros.ros.rig import RosRig, domain_for

    sent_node: dict[tuple[str, str], list[Sent]] = {}
    sent_floor: dict[tuple[str, str], list[Sent]] = {}
    service: list[float] = []
    # 20 ms and 1 ms are whole and half multiples of the 400 µs cycle: sent on a strict
    # schedule, every value would meet the cycle at the same phase, and the wait for the next
    # frame would be fixed by when the pattern happened to start. Dithered by up to one cycle,
    # the phase is uniform, and the wait averages half a cycle.
    dither = _cycle_ns() / 1e9
    with RosRig(CONFIG) as rig, contextlib.ExitStack() as stack:
        client = rig.client
        client.wait_for_node()
        client.layout(timeout=10)
        assert rig.veth is not None
        sniffer = WireSniffer(rig.veth.slave, _variable_offset())
        stack.callback(sniffer.close)
        floor_domain = domain_for(os.getpid(), FLOOR_DOMAIN_OFFSET)
        subscriber = Worker(["subscribe"], floor_domain, "the floor subscriber")
        stack.callback(subscriber.close)
        subscriber.expect_ready()
        to_floor = CommandSender(floor_domain)
        stack.callback(to_floor.close)
        to_node = CommandSender(rig.domain_id)
        stack.callback(to_node.close)
        for variant, _ in VARIANTS:
            if variant == "quiet":
                for name in ("ros.raw_decimation", "ros.decoded_decimation"):
                    ok, reason = client.set_parameter(name, 1_000_000)
                    if not ok:
                        raise BenchSkipped(reason)
                time.sleep(0.5)
            # Interleaved, so that the floor sees the same load on the machine as the node.
            for pattern, _, gap, sender in PATTERNS:
                sent_floor[variant, pattern] = to_floor.send(gap, samples, dither, sender)
                sent_node[variant, pattern] = to_node.send(gap, samples, dither, sender)
        time.sleep(0.1)  # the last value reaches the wire
        sniffer.close()
        to_floor.end()
        woken = {int(k): v for k, v in json.loads(subscriber.line(30)).items()}
        for i in range(samples // 2):
            t0 = time.perf_counter_ns()
            ok, _ = client.write(SLAVE, VARIABLE, 500 + i)
            if ok:
                service.append(time.perf_counter_ns() - t0)
            time.sleep(0.01)
    all_sent = [s for key in sent_node for s in sent_node[key]]
    frames = first_frames(all_sent, sniffer.changes)
    node = {key: _wire_path(sent, frames) for key, sent in sent_node.items()}
    floor = {key: _floor_path(sent, woken) for key, sent in sent_floor.items()}
    return node, floor, service, sniffer


def _topic_to_wire(report: Report, samples: int) -> None:
    node, floor, service, sniffer = _measure(samples)
    read_delay = sniffer.min_read_delay_ns
    if not any(p.call_to_end for p in node.values()):
        raise BenchSkipped("no published value was seen on the wire")
    if read_delay is not None and not 0 <= read_delay < 1_000_000_000:
        raise ToolError(f"frame timestamps are not on time.time_ns()'s clock ({read_delay} ns)")
    cycle = _cycle_ns()
    target = cycle + TARGET_MARGIN_NS
    descr = {name: d for name, d, _, _ in PATTERNS}

    report.text(
        "### Command latency over ROS 2 (µs, p50 / p99 / max)\n\n"
        f"{samples} values per row, sent by a process of their own. Patterns: *sparse*, one "
        "value every 20 ms (the sender idles in between, so its caches and vCPU go cold: every "
        "step is several times slower than in a stream); *stream*, a new value every 1 ms, as a "
        "locomotion controller sends; each send is moved by a random 0..1 cycle so that its "
        "phase to the master's cycle is uniform (both intervals are multiples of half a "
        "cycle). How to read it: *call → wire* (the headline; from right "
        "before `publish()` to the kernel timestamp of the first frame carrying the value; "
        f"target: one cycle + {us(TARGET_MARGIN_NS)} = {us(target)} µs at p99) = *publish()* "
        "(the call itself, paid by the sender) + *returned → wire*; and *returned → wire* = "
        "the DDS delivery (the floor, next table) + the wait for the next frame + the "
        "node's own share (split in *Where the time goes*). *building*: constructing the "
        "`WriteVariable` before the call, not part of any latency here."
    )
    rows = []
    for variant, vlabel in VARIANTS:
        for pattern, _, _, _ in PATTERNS:
            p = node[variant, pattern]
            rows.append([vlabel, f"{pattern} ({descr[pattern]})", len(p.call_to_end),
                         _cell(p.call_to_end), _cell(p.returned_to_end), _cell(p.publish),
                         us(_percentile(p.construct, 0.5))])  # fmt: skip
            key = f"node_{variant}_{pattern}"
            _record(report, f"{key}_call_to_wire", p.call_to_end)
            _record(report, f"{key}_returned_to_wire", p.returned_to_end)
            _record(report, f"{key}_publish", p.publish)
            _record(report, f"{key}_construct", p.construct)
            report.value(f"{key}_missed", p.missed)
            report.value(f"{key}_superseded", p.superseded)
    report.table(["path", "pattern", "samples", "call → wire", "returned → wire",
                  "publish()", "building p50"], rows)  # fmt: skip
    verdicts = []
    for pattern, _, _, _ in PATTERNS:
        p99 = _percentile(node["publishing", pattern].call_to_end, 0.99)
        verdicts.append(f"{pattern} {us(p99)} µs ({'met' if p99 <= target else 'not met'})")
    stream = node["publishing", "stream"].interval
    report.text(
        f"With the node publishing, call → wire p99 against the target {us(target)} µs: "
        f"{', '.join(verdicts)}. The stream's "
        f"sender kept an interval of {us(_percentile(stream, 0.5))} µs p50, "
        f"{us(_percentile(stream, 0.99))} µs p99 between values."
    )
    for variant, vlabel in VARIANTS:
        _record(report, f"sender_{variant}_stream_interval", node[variant, "stream"].interval)
        # A node that cannot keep up with the stream queues commands: the latency then grows
        # along the stream instead of staying level, and its percentiles depend on the
        # stream's length. Said so when it happens.
        first, last = _tenths(node[variant, "stream"].call_to_end)
        report.value(f"node_{variant}_stream_first_tenth_p50_ns", first)
        report.value(f"node_{variant}_stream_last_tenth_p50_ns", last)
        if last > 2 * first + cycle:
            report.text(
                f"With the {vlabel}, the node did not keep up with the stream: call → wire "
                f"grew from {us(first)} µs (p50 of the first tenth of the values) to "
                f"{us(last)} µs (last tenth); commands queue up in front of it."
            )
    # The keys of earlier runs (sparse pattern), for comparisons.
    for variant, key in (("publishing", "topic_to_wire"), ("quiet", "topic_to_wire_quiet")):
        _record(report, key, node[variant, "sparse"].call_to_end)
    missed = sum(p.missed for p in node.values())
    superseded = sum(p.superseded for p in node.values())
    report.value("topic_to_wire_missed", missed)
    report.value("topic_to_wire_superseded", superseded)
    if missed or superseded or sniffer.dropped:
        report.text(
            f"Values never seen on the wire: {missed}; replaced by the next value before a "
            f"frame carried them: {superseded} (timed to the frame carrying the "
            f"successor); the sniffer's socket dropped {sniffer.dropped} of "
            f"{sniffer.frames + sniffer.dropped} frames (a dropped frame can make a value look "
            "later than it was)."
        )

    report.text(
        "### The DDS floor: the same sender, a minimal subscriber, no node (µs, p50 / p99 / max)"
        "\n\nMeasured in the same run, interleaved with the rows above (same load on the "
        "machine). *returned → received*: `publish()` returned → the middleware in the "
        "subscriber's process had the sample (its own `received_timestamp`; negative when "
        "delivery finishes inside `publish()`); *received → woken*: → the subscriber's "
        "`rcl_wait` returned into Python; *returned → woken*: both; *take*: `take_message` in "
        "Python after that (the node does not pay it on its native command path)."
    )
    rows = []
    for variant, vlabel in VARIANTS:
        for pattern, _, _, _ in PATTERNS:
            p = floor[variant, pattern]
            rows.append([vlabel, pattern, len(p.returned_to_end), _cell(p.returned_to_received),
                         _cell(p.received_to_woken), _cell(p.returned_to_end), _cell(p.publish),
                         _cell(p.take)])  # fmt: skip
            key = f"floor_{variant}_{pattern}"
            _record(report, f"{key}_returned_to_received", p.returned_to_received)
            _record(report, f"{key}_received_to_woken", p.received_to_woken)
            _record(report, f"{key}_returned_to_woken", p.returned_to_end)
            _record(report, f"{key}_call_to_woken", p.call_to_end)
            _record(report, f"{key}_publish", p.publish)
            _record(report, f"{key}_take", p.take)
            report.value(f"{key}_missed", p.missed)
    report.table(["while", "pattern", "samples", "returned → received", "received → woken",
                  "returned → woken", "publish()", "take"], rows)  # fmt: skip

    report.text(
        "### Where the time goes (µs)\n\n"
        "The mean of *call → wire* split into its parts (every mean here leaves out the "
        "slowest 1 % of its sample set: the VM's millisecond stalls are in the p99 and max "
        "columns above, and would otherwise swing a whole column): *publish()*, the sender's "
        "call; *DDS*, the floor's *returned → received* (the middleware delivering the sample "
        "into the other process); *frame wait*: the value is applied at a uniformly random "
        f"point of the {us(cycle)} µs cycle, so the next frame is on average {us(cycle / 2)} µs "
        f"and at most {us(cycle)} µs away; *node*, what remains: the node's own share (waking "
        "its command thread, taking the message, applying it to the output image). Means add "
        "up; percentiles do not, so *node + frame wait p50 / p99* are differences of "
        "percentiles (the node's *returned → wire* minus the floor's *returned → received*) of "
        "two separate sample sets, not percentiles of a difference: a rough guide, which can "
        "even come out negative on this noisy VM. *node vs Python*: the node's share computed "
        "against the floor's Python subscriber (*returned → woken*) instead; below zero, the "
        "node takes and applies a command faster than a Python wait set merely wakes up."
    )
    rows = []
    breakdowns: list[tuple[str, str, list[tuple[str, float]]]] = []
    for variant, vlabel in VARIANTS:
        for pattern, _, _, _ in PATTERNS:
            n = node[variant, pattern]
            f = floor[variant, pattern]
            if not n.returned_to_end or not f.returned_to_end:
                continue
            key = f"{variant}_{pattern}"
            call, returned = _mean(n.publish), _mean(n.returned_to_end)
            total = call + returned  # so that the parts add up to it exactly
            vs_python = returned - _mean(f.returned_to_end) - cycle / 2
            report.value(f"node_own_mean_vs_python_{key}_ns", vs_python)
            report.value(f"node_call_to_wire_mean_{key}_ns", total)
            if not f.returned_to_received:
                rows.append([vlabel, pattern, us(total), us(call), "-", us(cycle / 2), "-", "-",
                             us(vs_python)])  # fmt: skip
                continue
            received = f.returned_to_received
            dds = _mean(received)
            own = returned - dds - cycle / 2
            d50 = _percentile(n.returned_to_end, 0.5) - _percentile(received, 0.5)
            d99 = _percentile(n.returned_to_end, 0.99) - _percentile(received, 0.99)
            rows.append([vlabel, pattern, us(total), us(call), us(dds), us(cycle / 2), us(own),
                         f"{us(d50)} / {us(d99)}", us(vs_python)])  # fmt: skip
            if variant == VARIANTS[0][0]:
                parts = [("publish()", call), ("DDS", dds), ("frame wait", cycle / 2),
                         ("node", own)]  # fmt: skip
                breakdowns.append((vlabel, pattern, parts))
            report.value(f"node_share_{key}_p50_ns", d50)
            report.value(f"node_share_{key}_p99_ns", d99)
            report.value(f"node_own_mean_{key}_ns", own)
            report.value(f"dds_mean_{key}_ns", dds)
    report.table(["path", "pattern", "call → wire (mean)", "= publish()", "+ DDS",
                  "+ frame wait", "+ node", "node + frame wait p50 / p99",
                  "node vs Python"], rows)  # fmt: skip
    for vlabel, pattern, parts in breakdowns:
        total = sum(v for _, v in parts)
        shares = ", ".join(f"{name} {100 * v / total:.0f} %" for name, v in parts)
        report.text(f"{vlabel}, {pattern}: of the mean call → wire, {shares}.")

    report.text("### Service round trip (µs)")
    report.table(["path", "samples", "p50", "p99", "max"],
                 [["write_variables service round trip", len(service),
                   us(_percentile(service, 0.5)), us(_percentile(service, 0.99)),
                   us(max(service, default=0))]])  # fmt: skip
    _record(report, "service_rtt", service)
    report.value("sniffer_min_read_delay_ns", read_delay)
    report.value("sniffer_frames", sniffer.frames)
    report.value("sniffer_dropped", sniffer.dropped)
    _python_command_path(report, samples, node)


def _python_command_path(
    report: Report, samples: int, native: dict[tuple[str, str], Timings]
) -> None:
    """The same senders against a node whose pdo_listener is served by the Python executor
    (`ether-ros run --python-commands`, the path before the native one): what the native
    command thread saves, in the same run."""
    from ether_ros.ros.rig import RosRig, domain_for

    patterns = [p for p in PATTERNS if p[0] != "sparse"]
    sent: dict[str, list[Sent]] = {}
    dither = _cycle_ns() / 1e9
    domain = domain_for(os.getpid(), PYTHON_DOMAIN_OFFSET)
    rig = RosRig(CONFIG, domain_id=domain, node_args=["--python-commands"])
    with rig, contextlib.ExitStack() as stack:
        rig.client.wait_for_node()
        rig.client.layout(timeout=10)
        assert rig.veth is not None
        sniffer = WireSniffer(rig.veth.slave, _variable_offset())
        stack.callback(sniffer.close)
        sender = CommandSender(rig.domain_id)
        stack.callback(sender.close)
        for pattern, _, gap, kind in patterns:
            sent[pattern] = sender.send(gap, samples, dither, kind)
        time.sleep(0.1)
        sniffer.close()
    frames = first_frames([s for values in sent.values() for s in values], sniffer.changes)
    rows = []
    for pattern, _, _, _ in patterns:
        python = _wire_path(sent[pattern], frames)
        fast = native["publishing", pattern]
        ratios = [
            _percentile(python.call_to_end, q) / max(_percentile(fast.call_to_end, q), 1.0)
            for q in (0.5, 0.99)
        ]
        rows.append([pattern, _cell(fast.call_to_end), _cell(python.call_to_end),
                     f"{ratios[0]:.1f}× / {ratios[1]:.1f}×"])  # fmt: skip
        _record(report, f"python_path_{pattern}_call_to_wire", python.call_to_end)
    report.text("### The native command path against the Python executor (µs, p50 / p99 / max)")
    report.text(
        "call → wire with the node publishing at 2.5 kHz: the native command thread (rows above) "
        "and the same node with `--python-commands` (pdo_listener on the Python executor, as "
        "before the native path), the same senders, measured in this run."
    )
    report.table(["pattern", "native", "Python executor", "Python / native p50 / p99"], rows)


def _one_run(seconds: float, publish: bool) -> dict[str, float]:
    from ether_ros.ros.rig import RosRig, domain_for

    with RosRig(CONFIG, domain_id=domain_for(os.getpid(), 3 if publish else 4)) as rig:
        client = rig.client
        client.wait_for_node()
        if not publish:
            for name in ("ros.raw_decimation", "ros.decoded_decimation"):
                ok, reason = client.set_parameter(name, 1_000_000)
                if not ok:
                    raise BenchSkipped(reason)
        assert rig.node_proc is not None
        pid = rig.node_proc.pid
        cpu0, t0 = _cpu_seconds(pid), time.monotonic()
        n0 = client.latest.counts.get("diagnostics", 0)
        time.sleep(seconds)
        cpu = (_cpu_seconds(pid) - cpu0) / (time.monotonic() - t0)
        client.wait_for(lambda latest: latest.counts.get("diagnostics", 0) > n0 + 1, 5)
        status = client.master_status()
    out = {k: float(v) for k, v in status.items() if k.endswith("_ns") or k.startswith("ros_")
           or k in ("cycles", "lost_frames", "overruns")}  # fmt: skip
    out["node_cpu_percent"] = 100.0 * cpu
    return out


def _publish_vs_latency(report: Report, seconds: float) -> None:
    on = _one_run(seconds, publish=True)
    off = _one_run(seconds, publish=False)
    rows = []
    for key, label in (
        ("wake_latency_p50_ns", "wake-up latency p50 (µs)"),
        ("wake_latency_p99_ns", "wake-up latency p99 (µs)"),
        ("wake_latency_max_ns", "wake-up latency max (µs)"),
        ("period_p99_ns", "period p99 (µs)"),
        ("exec_p99_ns", "execution p99 (µs)"),
    ):
        rows.append([label, us(on.get(key, 0)), us(off.get(key, 0))])
    rows.append(["node process CPU (%)", f"{on['node_cpu_percent']:.0f}",
                 f"{off['node_cpu_percent']:.0f}"])  # fmt: skip
    for key, label in (("ros_published_raw", "pdo_raw messages"),
                       ("ros_dropped", "samples dropped by ROS"),
                       ("lost_frames", "lost frames"), ("overruns", "overruns")):  # fmt: skip
        rows.append([label, f"{on.get(key, 0):.0f}", f"{off.get(key, 0):.0f}"])
    report.text(
        f"### Publishing every cycle vs not ({seconds:g} s each after start-up; "
        "histograms since the node started)"
    )
    report.table(["", "publishing (raw every cycle, decoded every 10th)", "not publishing"], rows)
    report.value("publishing", on)
    report.value("not_publishing", off)


def run(report: Report) -> None:
    if os.geteuid() != 0:
        raise BenchSkipped("needs root (veth pairs)")
    try:
        import ether_ros_msgs  # noqa: F401
    except ImportError as exc:
        raise BenchSkipped(f"ether_ros_msgs not built: {exc}") from None
    _topic_to_wire(report, 300 if report.quick else 1000)
    _publish_vs_latency(report, 4.0 if report.quick else 12.0)
