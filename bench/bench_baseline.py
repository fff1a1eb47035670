"""Baselines of this machine, measured in the same run as the other benchmarks: how late a
SCHED_FIFO thread wakes (cyclictest) and how long a minimal C EtherCAT echo takes to answer over
a veth pair (the floor under any simulator or master round trip)."""

from __future__ import annotations

from baseline import cyclictest, echo_responder, rtt_probe
from ether_ros.testing.netns import VethPair
from report import Report, us


def run(report: Report) -> None:
    seconds = 2.0 if report.quick else 10.0
    rows = []
    for interval in (50, 400):
        h = cyclictest(interval_us=interval, seconds=seconds)
        rows.append(
            [
                f"{interval} µs ({1e6 / interval / 1000:g} kHz)",
                h.total,
                h.min_us,
                h.percentile(50),
                h.percentile(99),
                h.percentile(99.9),
                h.max_us,
                h.overflows,
            ]
        )
        report.value(
            f"cyclictest_{interval}us",
            {
                "samples": h.total,
                "p50_us": h.percentile(50),
                "p99_us": h.percentile(99),
                "p999_us": h.percentile(99.9),
                "max_us": h.max_us,
            },
        )
    report.text(
        f"Wake-up latency of one SCHED_FIFO 80 thread, memory locked "
        f"(`cyclictest -m -p 80 -i <interval> -D {seconds:g}s -q -h 1000`), µs:"
    )
    report.table(["interval", "samples", "min", "p50", "p99", "p99.9", "max", "> 1 ms"], rows)

    frames = 2_000 if report.quick else 20_000
    with (
        VethPair.create(netns=True) as veth,
        echo_responder(veth.slave, netns=veth.netns, priority=70),
    ):
        pingpong = rtt_probe(veth.master, frames=frames, priority=75)
        paced = rtt_probe(veth.master, rate_hz=20_000, seconds=seconds / 2, priority=75)
    rows = []
    for label, r in (("ping-pong", pingpong), ("paced 20 kHz", paced)):
        q = r.rtt_ns
        rows.append(
            [
                label,
                r.sent,
                r.lost,
                f"{r.rate_hz:.0f}",
                us(q["min"]),
                us(q["p50"]),
                us(q["p99"]),
                us(q["p999"]),
                us(q["max"]),
            ]
        )
        report.value(
            f"echo_{label.split()[0].replace('-', '')}",
            {"sent": r.sent, "lost": r.lost, "rate_hz": r.rate_hz, "rtt_ns": q},
        )
    report.text(
        "Round trip of a 240-byte LRW frame (the Laelaps II cyclic frame) through a veth pair "
        "to the C echo responder in its own network namespace (`bench/c/echo.c`, "
        "`bench/c/rtt.c`; echo SCHED_FIFO 70 like the simulator's frame thread, probe 75), µs:"
    )
    report.table(["mode", "frames", "lost", "rate Hz", "min", "p50", "p99", "p99.9", "max"], rows)
