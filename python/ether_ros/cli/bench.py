"""``ether-ros bench cycle``: bring a bus to OP and run the cyclic exchange without ROS for a
while, then report what the engine measured: cycles, lost/late/unmatched frames, working
counter errors, and p50/p99/p99.9/max of wake-up latency, execution time, period and round trip.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from typing import Any

from ether_ros.cli.common import add_interface_argument, add_parser, resolve_interface
from ether_ros.errors import ConfigError
from ether_ros.master.link import add_link_argument

COUNTERS = (
    "cycles",
    "lost_frames",
    "late_frames",
    "unmatched_frames",
    "wkc_errors",
    "overruns",
)
HISTOGRAMS = (
    ("wake_latency", "wake-up latency"),
    ("exec", "execution time"),
    ("period", "period"),
    ("rtt", "round trip"),
)
PERCENTILES = (("p50", "p50"), ("p99", "p99"), ("p999", "p99.9"), ("max", "max"))


def register(subparsers: Any) -> None:
    p = add_parser(
        subparsers,
        "bench",
        help="benchmarks of the master",
        description="Benchmarks of the master on a bus (the repository's bench/ has the rest).",
        examples=["ether-ros bench cycle config/laelaps.yaml -i eth1 --seconds 10"],
    )
    sub = p.add_subparsers(dest="bench_command", metavar="BENCH", required=True)
    c = add_parser(
        sub,
        "cycle",
        help="run the cyclic exchange in OP and report latencies",
        description="Bring the bus of CONFIG to OP and measure the cyclic loop (no ROS): "
        "cycles, lost/late/unmatched frames, working counter errors, and percentiles of "
        "wake-up latency, execution time, period and round trip.",
        examples=[
            "ether-ros bench cycle config/laelaps.yaml -i eth1",
            "ether-ros bench cycle config/laelaps.yaml -i eth1 --cycle-us 100 --seconds 10 "
            "--json cycle.json",
        ],
    )
    c.add_argument("config", help="bus configuration (YAML)")
    add_interface_argument(c)
    add_link_argument(c)
    c.add_argument("--cycle-us", type=int, help="cycle time in µs (default: bus.cycle_us)")
    c.add_argument("--seconds", type=float, default=10.0, help="how long to run (default 10)")
    c.add_argument("--json", dest="json_file", help="also write the results to this JSON file")
    c.add_argument(
        "--drift-frames",
        type=int,
        default=None,
        help="static DC drift compensation frames at start-up (default 3000)",
    )
    c.set_defaults(func=run_cycle)


def _counter(stats: dict[str, Any], name: str) -> int:
    if name in stats and not isinstance(stats[name], dict):
        return int(stats[name])
    inner = stats.get("counters")
    if isinstance(inner, dict) and name in inner:
        return int(inner[name])
    return 0


def _histogram(stats: dict[str, Any], name: str) -> dict[str, float]:
    h = stats.get(name)
    if not isinstance(h, dict):
        inner = stats.get("histograms")
        h = inner.get(name) if isinstance(inner, dict) else None
    return dict(h) if isinstance(h, dict) else {}


def summarize(stats: dict[str, Any], seconds: float, cycle_us: int) -> dict[str, Any]:
    """The benchmark result: counters and per-histogram percentiles in µs."""
    result: dict[str, Any] = {"seconds": seconds, "cycle_us": cycle_us}
    result.update({name: _counter(stats, name) for name in COUNTERS})
    for key, _label in HISTOGRAMS:
        h = _histogram(stats, key)
        result[key + "_us"] = {
            p: (float(h[p]) / 1000.0 if p in h else None) for p, _ in PERCENTILES
        }
    result["frames"] = len(stats.get("frames") or [])
    result["groups"] = [
        {k: g[k] for k in ("name", "every", "frames", "sent", "lost", "late", "wkc_errors",
                           "watchdog_trips", "expected_wkc", "last_wkc")}
        | {"cycle_us": g["cycle_ns"] / 1000}
        for g in stats.get("groups") or []
    ]  # fmt: skip
    return result


def format_result(result: dict[str, Any]) -> str:
    lines = [
        f"cycle {result['cycle_us']} µs for {result['seconds']:g} s: {result['cycles']} cycles, "
        f"{result['lost_frames']} lost, {result['late_frames']} late, "
        f"{result['unmatched_frames']} unmatched frames, {result['wkc_errors']} WKC errors",
        f"{'(µs)':<18}" + "".join(f"{label:>10}" for _p, label in PERCENTILES),
    ]
    for key, label in HISTOGRAMS:
        row = result[key + "_us"]
        cells = "".join(
            f"{row[p]:>10.1f}" if row[p] is not None else f"{'-':>10}" for p, _ in PERCENTILES
        )
        lines.append(f"{label:<18}{cells}")
    for g in result.get("groups") or []:
        lines.append(
            f"group {g['name']}: cycle {g['cycle_us']:g} µs, frames {g['frames']}, "
            f"{g['sent']} sent, {g['lost']} lost, {g['late']} late, {g['wkc_errors']} WKC "
            f"errors, WKC {g['last_wkc']}/{g['expected_wkc']}"
        )
    return "\n".join(lines)


def run_cycle(args: argparse.Namespace) -> int:
    from ether_ros.config import load_bus_config
    from ether_ros.master.bus import Bus

    if args.seconds <= 0:
        raise ConfigError(f"--seconds must be positive, got {args.seconds}")
    cfg = load_bus_config(args.config, interface=args.interface, link=args.link)
    cfg.bus.interface = resolve_interface(args, cfg.bus.interface, "bench cycle", args.config)
    if args.cycle_us is not None:
        if not 20 <= args.cycle_us <= 1_000_000:
            raise ConfigError(f"--cycle-us must be 20..1000000, got {args.cycle_us}")
        # Groups keep their rate in bus cycles.
        for g in cfg.groups:
            g.cycle_us = g.cycle_us // cfg.bus.cycle_us * args.cycle_us
        cfg.bus.cycle_us = args.cycle_us
        shift = cfg.bus.dc.sync0_shift_us
        if shift >= args.cycle_us:
            cfg.bus.dc.sync0_shift_us = args.cycle_us / 2
    t_open = time.monotonic()
    with Bus.open(cfg, drift_frames=args.drift_frames) as bus:
        bus.start()
        bringup_s = time.monotonic() - t_open
        # Measure the steady state in OP only, not the bring-up before it.
        bus.engine.reset_stats()
        bus.samples()
        deadline = time.monotonic() + args.seconds
        while time.monotonic() < deadline:
            time.sleep(min(0.05, max(0.0, deadline - time.monotonic())))
            bus.samples()  # keep the ring from overflowing; the stats are what we report
            bus.feed_watchdog()  # the outputs stay as they are: no watchdog trips
        stats = dict(bus.stats())
        bus.stop()
    result = summarize(stats, args.seconds, int(cfg.bus.cycle_us))
    # Scan, SII, configuration and DC setup to OP (Bus.open + start).
    result["bringup_s"] = bringup_s
    print(format_result(result))
    if args.json_file:
        Path(args.json_file).write_text(json.dumps(result, indent=2) + "\n")
    return 0
