"""The ROS 2 interface: how long a command published on ROS takes to reach the wire, and what
publishing every cycle costs the real-time loop.

Setup: `RosRig` — the simulator (`ether-ros sim config/laelaps.yaml`, 4 Laelaps II legs) and the
node (`ether-ros run`, 400 µs cycle, SCHED_FIFO) in their own processes on a veth pair, and an
rclpy client in this process (its own ROS domain, localhost discovery).

1. Topic → wire: the client publishes a `WriteVariable` (front_left_leg `Kp100_hip` = a new value)
   on `pdo_listener`, ~40 per second; a raw socket on the simulator's end of the veth pair sees
   the frames the master sends. The latency is the kernel timestamp of the first frame whose LRW
   data carries the new value minus the time of `publish()` (same clock, same host). It includes DDS
   delivery, the node's executor, the output seqlock and up to one cycle of waiting for the next
   frame (400 µs). Measured with the node publishing as configured (`pdo_raw` every cycle) and
   with its publishing turned off. The `write_variables` service round trip is measured too.
2. Publishing at 2.5 kHz vs not: two runs of the node, one publishing `pdo_raw` every cycle
   (plus decoded values every 10th), one publishing nothing (decimations 10^6); the engine's
   wake-up latency and period (its own histograms, from `diagnostics`) and the node process's CPU
   use in each. The RT thread never waits for Python, so the latency should not move beyond the
   VM's run-to-run noise; the CPU use is what ROS costs.
"""

from __future__ import annotations

import os
import socket
import struct
import threading
import time
from pathlib import Path
from typing import Any

from report import BenchSkipped, Report, us

REPO = Path(__file__).resolve().parent.parent
CONFIG = REPO / "config" / "laelaps.yaml"
SLAVE = "front_left_leg"
VARIABLE = "Kp100_hip"


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


def _cpu_seconds(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


ETH_P_ALL = 0x0003
LRW = 0x0C
SO_TIMESTAMPNS = 35
SCM_TIMESTAMPNS = SO_TIMESTAMPNS


class WireSniffer:
    """Watches the frames the master sends, as they arrive at the simulator's end of the veth
    pair, and notes the kernel timestamp of the first frame whose LRW data carries the
    value wanted at ``offset`` of the process image (one LRW covers the whole image here)."""

    def __init__(self, interface: str, offset: int) -> None:
        self.offset = offset
        self.want: int | None = None
        self.seen_ns: int | None = None
        self.event = threading.Event()
        self.frames = 0
        # The master's socket bypasses the qdisc (and with it the taps on its own end), so the
        # frames are taken where they arrive: the simulator's end of the pair.
        self._sock = socket.socket(socket.AF_PACKET, socket.SOCK_RAW, socket.htons(ETH_P_ALL))
        self._sock.setsockopt(socket.SOL_SOCKET, SO_TIMESTAMPNS, 1)
        self._sock.bind((interface, ETH_P_ALL))
        self._sock.settimeout(0.2)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def close(self) -> None:
        self._stop.set()
        self._thread.join(2)
        self._sock.close()

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                frame, ancillary, _flags, address = self._sock.recvmsg(2048, 64)
            except TimeoutError:
                continue
            except OSError:
                return
            if address[2] == socket.PACKET_OUTGOING or frame[12:14] != b"\x88\xa4":
                continue
            self.frames += 1
            want = self.want
            if want is None or self.event.is_set():
                continue
            value = self._lrw_value(frame)
            if value == want:
                stamp = time.time_ns()
                for level, kind, data in ancillary:
                    if level == socket.SOL_SOCKET and kind == SCM_TIMESTAMPNS:
                        sec, nsec = struct.unpack("qq", data[:16])
                        stamp = sec * 1_000_000_000 + nsec
                self.seen_ns = stamp
                self.event.set()

    def _lrw_value(self, frame: bytes) -> int | None:
        pos = 16  # Ethernet header (14) + EtherCAT header (2)
        while pos + 10 <= len(frame):
            cmd = frame[pos]
            length = struct.unpack_from("<H", frame, pos + 6)[0]
            more, length = length & 0x8000, length & 0x07FF
            data = pos + 10
            if cmd == LRW and self.offset + 2 <= length:
                return int(struct.unpack_from("<h", frame, data + self.offset)[0])
            if not more:
                return None
            pos = data + length + 2
        return None


def _topic_to_wire(report: Report, samples: int) -> None:
    from ether_ros.ros.rig import RosRig

    with RosRig(CONFIG) as rig:
        client = rig.client
        client.wait_for_node()
        client.layout(timeout=10)
        assert rig.veth is not None
        sniffer = WireSniffer(rig.veth.slave, _variable_offset())
        try:
            latencies, missed = _measure(client, sniffer, samples)
            # The same without the node publishing anything (how much the 2.5 kHz publishing
            # delays a command).
            for name in ("ros.raw_decimation", "ros.decoded_decimation"):
                client.set_parameter(name, 1_000_000)
            time.sleep(0.5)
            quiet, missed_quiet = _measure(client, sniffer, samples)
        finally:
            sniffer.close()
        service: list[float] = []
        for i in range(samples // 2):
            t0 = time.perf_counter_ns()
            ok, _ = client.write(SLAVE, VARIABLE, 500 + i)
            if ok:
                service.append(time.perf_counter_ns() - t0)
            time.sleep(0.01)
    if not latencies or not quiet:
        raise BenchSkipped("no published value was seen on the wire")
    rows = []
    for label, key, values in (
        ("publish → frame on the wire (node publishing at 2.5 kHz)", "topic_to_wire", latencies),
        ("publish → frame on the wire (node not publishing)", "topic_to_wire_quiet", quiet),
        ("write_variables service round trip", "service_rtt", service),
    ):
        p50, p99 = _percentile(values, 0.5), _percentile(values, 0.99)
        rows.append([label, len(values), us(p50), us(p99), us(max(values))])
        report.value(f"{key}_p50_ns", p50)
        report.value(f"{key}_p99_ns", p99)
    report.text("### Command latency over ROS 2 (µs)")
    report.table(["path", "samples", "p50", "p99", "max"], rows)
    if missed or missed_quiet:
        report.text(f"{missed + missed_quiet} of {2 * samples} values were not seen within 1 s.")
    report.value("topic_to_wire_missed", missed + missed_quiet)


def _measure(client: Any, sniffer: WireSniffer, samples: int) -> tuple[list[float], int]:
    latencies: list[float] = []
    missed = 0
    for i in range(samples):
        value = 1000 + (i * 7919) % 20000
        sniffer.want, sniffer.seen_ns = value, None
        sniffer.event.clear()
        t_pub = time.time_ns()
        client.publish_write(SLAVE, VARIABLE, value)
        if sniffer.event.wait(1.0) and sniffer.seen_ns is not None:
            latencies.append(sniffer.seen_ns - t_pub)
        else:
            missed += 1
        time.sleep(0.02)
    return latencies, missed


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
    _topic_to_wire(report, 60 if report.quick else 300)
    _publish_vs_latency(report, 4.0 if report.quick else 12.0)
