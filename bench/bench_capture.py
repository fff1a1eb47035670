"""What a capture on the master's own interface costs: frames sent straight to the driver
(``PACKET_QDISC_BYPASS``, the default) against frames through the kernel's transmit queue
(``bus.capture: true``), with and without a capture actually listening.

Setup as bench_links: the simulator (4 Laelaps II legs) in its own network namespace at the far
end of a veth pair, the engine on the near end with the thesis's cyclic frame (DC datagrams and
a 240-byte LRW), send_at_wake, SCHED_FIFO 80, memory locked, AF_PACKET. Rows:

- ``bypass``: the default; a capture on the master's interface sees none of its frames;
- ``queue``: ``qdisc_bypass=False``: the frames go through the interface's queueing discipline
  (and ``dev_queue_xmit``'s taps), nobody listening;
- ``queue + capture``: the same with a raw ``ETH_P_ALL`` socket on the master's interface
  reading every frame, as tcpdump does: the kernel clones each frame to it.

The windows alternate (bypass, queue, queue + capture, bypass, ...) so a load change on the
shared VM hits every row alike; the columns sum each row's windows. Per row: execution (wake-up
→ the frame handed to the kernel and ``send`` returned), the time inside ``send`` alone,
wake-up latency, lost frames, and what the capture saw (outgoing EtherCAT frames per cycle).
Ratios are against ``bypass`` in the same run.
"""

from __future__ import annotations

import socket
import threading
import time
from typing import Any

from baseline import simulator
from bench_engine import CONFIG, IMAGE, PRIORITY, _run_engine, address_slaves
from ether_ros.testing.netns import VethPair
from report import BenchSkipped, Report, us

LOOP_TIMES_US = (400, 100)
ROUNDS = 3
ETH_P_ALL = 0x0003
# (row, qdisc bypass, capture listening)
ROWS = (("bypass", True, False), ("queue", False, False), ("queue + capture", False, True))


class Capture:
    """A raw socket on the master's interface counting the outgoing EtherCAT frames it sees."""

    def __init__(self, interface: str) -> None:
        self.seen = 0
        self._sock = socket.socket(socket.AF_PACKET, socket.SOCK_RAW, socket.htons(ETH_P_ALL))
        self._sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4 << 20)
        self._sock.bind((interface, ETH_P_ALL))
        self._sock.settimeout(0.1)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                frame, address = self._sock.recvfrom(2048)
            except TimeoutError:
                continue
            except OSError:
                return
            if address[2] == socket.PACKET_OUTGOING and frame[12:14] == b"\x88\xa4":
                self.seen += 1

    def close(self) -> None:
        self._stop.set()
        self._thread.join(2)
        self._sock.close()


def _window(native: Any, interface: str, bypass: bool, listen: bool, loop_us: int,
            seconds: float) -> dict[str, Any]:  # fmt: skip
    engine = native.Engine.open_interface(interface, "packet", 0, bypass)
    capture = Capture(interface) if listen else None
    try:
        address_slaves(engine)
        engine.reset_stats()
        _run_engine(engine, "send_at_wake", seconds, cycle_us=loop_us)
        st = dict(engine.stats())
    finally:
        engine.close()
        if capture is not None:
            time.sleep(0.1)
            capture.close()
    st["captured"] = capture.seen if capture is not None else None
    return st


def _merge(into: dict[str, Any], st: dict[str, Any]) -> None:
    """Sum counters; keep each window's histogram summaries to take the median of."""
    for key in ("cycles", "lost_frames", "send_errors"):
        into[key] = into.get(key, 0) + int(st[key])
    for key in ("exec", "send", "wake_latency"):
        into.setdefault(key, []).append(st[key])
    if st["captured"] is not None:
        into["captured"] = into.get("captured", 0) + st["captured"]


def _median(summaries: list[dict[str, float]], q: str) -> float:
    values = sorted(float(s[q]) for s in summaries)
    return values[len(values) // 2] if values else float("nan")


def run(report: Report) -> None:
    try:
        import ether_ros._native as native
    except ImportError as e:
        raise BenchSkipped(f"ether_ros._native is not built: {e}") from e
    window = 1.5 if report.quick else 4.0
    results: dict[tuple[int, str], dict[str, Any]] = {}
    with VethPair.create(netns=True) as veth, simulator(CONFIG, veth.slave, veth.netns):
        for loop_us in LOOP_TIMES_US:
            for _ in range(ROUNDS):
                for name, bypass, listen in ROWS:
                    st = _window(native, veth.master, bypass, listen, loop_us, window)
                    _merge(results.setdefault((loop_us, name), {}), st)
    table = []
    for loop_us in LOOP_TIMES_US:
        base = results[(loop_us, "bypass")]
        for name, _, listen in ROWS:
            r = results[(loop_us, name)]
            ex50, ex99 = _median(r["exec"], "p50"), _median(r["exec"], "p99")
            se50, se99 = _median(r["send"], "p50"), _median(r["send"], "p99")
            wl99 = _median(r["wake_latency"], "p99")
            ratio = " / ".join(
                f"{a / b:.2f}" if b > 0 else "–"
                for a, b in (
                    (ex50, _median(base["exec"], "p50")),
                    (ex99, _median(base["exec"], "p99")),
                    (se50, _median(base["send"], "p50")),
                )
            )
            seen = f"{r['captured'] / max(r['cycles'], 1):.2f}" if listen else "–"
            table.append([loop_us, name, r["cycles"],
                          f"{100 * r['lost_frames'] / max(r['cycles'], 1):.2f} %",
                          f"{us(ex50)} / {us(ex99)}", f"{us(se50)} / {us(se99)}", us(wl99),
                          seen, ratio])  # fmt: skip
            report.value(f"{name}@{loop_us}", {
                "cycles": r["cycles"], "lost": r["lost_frames"],
                "exec_p50": ex50, "exec_p99": ex99, "send_p50": se50, "send_p99": se99,
                "wake_p99": wl99, "captured": r.get("captured"),
            })  # fmt: skip
    report.text(
        f"4 legs ({IMAGE}-byte LRW + DC datagrams), send_at_wake, SCHED_FIFO {PRIORITY}, "
        f"AF_PACKET on veth; {ROUNDS} alternating windows of {window:g} s per row and loop time "
        "(execution, send and wake-up columns: the median of the windows' percentiles). "
        "*captured / cycle*: outgoing EtherCAT frames a raw socket on the master's interface "
        "saw per cycle (1 frame per cycle is sent, plus mailbox frames); with the bypass a "
        "capture there sees nothing, which is why `bus.capture` exists."
    )
    report.table(["loop (µs)", "send path", "cycles", "lost", "execution p50 / p99 (µs)",
                  "send() p50 / p99 (µs)", "wake-up p99 (µs)", "captured / cycle",
                  "ratio vs bypass: exec p50 / exec p99 / send p50"], table)  # fmt: skip
