"""Thesis Table 6.5 as a sweep: how short can the EtherCAT loop time get before frames are lost?

The thesis ran EtherLab on the Laelaps II hardware (4 legs, 240-byte frame) and counted skipped
packets per loop time: with the generic (Linux network stack) driver 400 µs (2.5 kHz) was clean,
350 µs only after optimizations; with the native driver down to 230 µs (4.35 kHz), below which
the slaves refused OP. Here the same bus is the simulator (`ether-ros sim config/laelaps.yaml`,
its own process pinned to CPU 0, in a network namespace across a veth pair: the generic-driver
path, kernel network stack on both ends), and the master is `ether-ros bench cycle` (bring-up to
OP, then the engine's RT thread: SCHED_FIFO 80, memory locked, pinned to CPU 1, send_at_wake
order as in the thesis's IgH application). A fresh simulator and master per step; loop times
400 → 100 µs in steps of 50 µs, and 50 µs as a stretch.

Per step: lost frames (no reply by the time the next cycle is due: the thesis's "skipped
packets"), late frames (a reply that came after that), working-counter errors, and the round trip
and wake-up latency percentiles the engine reports; then the C probe (`bench/c/rtt.c`) through
the same simulator at the same rate, as the floor of the frame path without our master. When
frames were lost at 100 µs, a separate in-process run keeps every cycle's sample to show whether
the master or the reply was late. Target: zero lost frames at 100 µs.
"""

from __future__ import annotations

import json
import sys
import tempfile
from pathlib import Path
from typing import Any

BENCH = Path(__file__).resolve().parent
if str(BENCH) not in sys.path:  # when run as the diagnosis worker script
    sys.path.insert(0, str(BENCH))

from baseline import ToolError, parse_worker_args, rtt_probe, run_worker  # noqa: E402
from bench_master import (  # noqa: E402
    IMAGE,
    MASTER_CPU,
    PRIORITY,
    bench_cycle,
    fmt_us,
    pinned_simulator,
    write_config,
)
from ether_ros.testing.netns import VethPair  # noqa: E402
from report import BenchSkipped, Report  # noqa: E402

LOOP_TIMES_US = (400, 350, 300, 250, 200, 150, 100)
STRETCH_US = 50
TARGET_US = 100

# Thesis Table 6.5, skipped packets per loop time: EtherLab generic driver without / with the
# latency optimizations, EtherLab native driver. "not run": the thesis has no row for it.
NOT_RUN = "not run"
REFUSED = "slaves refused OP"
THESIS: dict[int, tuple[str, str, str]] = {
    400: ("0", "0", "0"),
    350: ("≈ 100", "0", "0"),
    300: (NOT_RUN, "≈ 100", "0"),
    250: (NOT_RUN, NOT_RUN, "0"),
}


def _thesis(loop_us: int) -> tuple[str, str, str]:
    # The native driver's slaves refused OP at 220 µs and below (thesis §6.2.2.2).
    return THESIS.get(loop_us, (NOT_RUN, NOT_RUN, REFUSED if loop_us <= 220 else NOT_RUN))


def _khz(loop_us: int) -> str:
    return f"{1000 / loop_us:.2f}"


def diagnose_worker(config: Path, interface: str, cycle_us: int, seconds: float, out: Path) -> int:
    """Run the master in this process for ``seconds`` at ``cycle_us``, keep every cycle's sample
    and write to ``out`` (JSON) what the engine was doing when it found a reply missing."""
    import time

    import numpy as np

    from ether_ros.config import load_bus_config
    from ether_ros.master.bus import Bus
    from ether_ros.master.samples import FLAGS

    cfg = load_bus_config(config, interface=interface)
    cfg.bus.cycle_us = cycle_us
    if cfg.bus.dc.sync0_shift_us >= cycle_us:
        cfg.bus.dc.sync0_shift_us = cycle_us / 2  # as `ether-ros bench cycle` does
    chunks = []
    with Bus.open(cfg) as bus:
        bus.start()
        bus.engine.reset_stats()
        bus.samples()
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline:
            time.sleep(0.02)
            chunks.append(bus.samples().records)
            bus.feed_watchdog()
        chunks.append(bus.samples().records)
        stats = dict(bus.stats())
        bus.stop()
    r = np.concatenate(chunks)
    # The LOST flag is set in the cycle that found the previous cycle's reply missing.
    lost = np.nonzero((r["flags"] & FLAGS["lost"]) != 0)[0]
    latency_us = r["wake_latency_ns"].astype(float) / 1000
    # When the lost frame left, after its planned instant: its cycle's wake-up latency + execution.
    lost = lost[lost > 0]
    sent_us = latency_us[lost - 1] + r["exec_ns"][lost - 1].astype(float) / 1000
    gaps = np.diff(lost)
    runs = np.split(lost, np.nonzero(gaps != 1)[0] + 1) if len(lost) else []

    def pct(values: Any, q: float) -> float | None:
        return float(np.percentile(values, q)) if len(values) else None

    result = {
        "cycles": len(r),
        "lost_frames": len(lost),
        "late_frames": int(stats.get("late_frames", 0)),
        "overruns": int(stats.get("overruns", 0)),
        "lost_sent_after_us": {"p50": pct(sent_us, 50), "p90": pct(sent_us, 90)},
        "lost_wake_latency_us": {
            "p50": pct(latency_us[lost], 50),
            "p90": pct(latency_us[lost], 90),
        },
        "wake_latency_us": {"p50": pct(latency_us, 50), "p99": pct(latency_us, 99)},
        "lost_after_lost": float((gaps == 1).mean()) if len(gaps) else 0.0,
        "bursts": len(runs),
        "longest_burst": max((len(x) for x in runs), default=0),
    }
    out.write_text(json.dumps(result, indent=2) + "\n")
    return 0


def _share(value: float | None) -> str:
    return "" if value is None else f"{100 * value:.2f} %"


def diagnose(config: Path, interface: str, cycle_us: int, seconds: float) -> dict[str, Any]:
    args = [str(config), interface, str(cycle_us), f"{seconds:g}"]
    return run_worker(Path(__file__).resolve(), "diagnose", args, timeout=seconds + 180)


def _diagnosis_text(d: dict[str, Any], cycle_us: int, seconds: float) -> str:
    head = (
        f"Where the lost frames at {cycle_us} µs come from (a separate {seconds:g} s run of the "
        "master in-process, every cycle's sample kept): "
        f"{d['lost_frames']} lost of {d['cycles']} cycles ({d['late_frames']} answered late), "
        f"{d['overruns']} overrun cycles."
    )
    if not d["lost_frames"]:
        return head
    sent, check, w = d["lost_sent_after_us"], d["lost_wake_latency_us"], d["wake_latency_us"]
    on_time = (
        sent["p50"] is not None
        and check["p50"] is not None
        and sent["p50"] < cycle_us / 4
        and check["p50"] < cycle_us / 4
    )
    return (
        f"{head} The lost frames had left {fmt_us(sent['p50'])} µs after their planned instant "
        f"at the median ({fmt_us(sent['p90'])} µs at p90), and the cycle that found the reply "
        f"missing had woken {fmt_us(check['p50'])} µs late ({fmt_us(check['p90'])} µs at p90; "
        f"all cycles: p50 {fmt_us(w['p50'])}, p99 {fmt_us(w['p99'])} µs): "
        + (
            "at the median the master sent and looked on time; the replies took more than a "
            "cycle to come back. "
            if on_time
            else "the master itself was late for many of them. "
        )
        + f"{100 * d['lost_after_lost']:.0f} % of the lost frames directly follow another lost "
        f"frame ({d['bursts']} runs, the longest {d['longest_burst']} cycles)."
    )


def run(report: Report) -> None:
    try:
        import ether_ros._native  # noqa: F401
    except ImportError as e:
        raise BenchSkipped(f"ether_ros._native is not built: {e}") from None
    seconds = 5.0 if report.quick else 60.0
    probe_seconds = max(2.0, seconds / 3)
    diagnosis_seconds = 5.0 if report.quick else 20.0
    steps = (*LOOP_TIMES_US, STRETCH_US)
    results: dict[int, dict[str, Any]] = {}
    errors: dict[int, str] = {}
    with tempfile.TemporaryDirectory(prefix="bench_sweep_") as tmp:
        config = write_config(Path(tmp), "send_at_wake")
        for loop_us in steps:
            print(f"[sweep] {loop_us} µs for {seconds:g} s", flush=True)
            try:
                with (
                    VethPair.create(netns=True) as veth,
                    pinned_simulator(config, veth.slave, veth.netns) as sim,
                ):
                    results[loop_us] = bench_cycle(config, veth.master, loop_us, seconds)
                    # The same path without our master: the C probe through the same simulator
                    # at the same rate, same frame size, same CPU and priority.
                    probe = rtt_probe(
                        veth.master,
                        rate_hz=1e6 / loop_us,
                        seconds=probe_seconds,
                        lrw_bytes=IMAGE,
                        priority=PRIORITY,
                        cpu=MASTER_CPU,
                        over_us=loop_us,
                    )
                    results[loop_us]["c_probe"] = {
                        "sent": probe.sent,
                        "answered": probe.answered,
                        # Replies a master cycling at this loop time would have counted lost.
                        "late_share": (probe.over + probe.lost) / max(probe.sent, 1),
                        "rtt_us": {k: v / 1000 for k, v in probe.rtt_ns.items()},
                    }
                    if sim.poll() is not None:
                        raise ToolError(f"the simulator exited ({sim.returncode})")
            except ToolError as e:
                last = str(e).splitlines()[-1][:300] if str(e) else type(e).__name__
                errors[loop_us] = last.replace("|", "/")  # it goes into a Markdown table
        diagnosis: dict[str, Any] | None = None
        diagnosis_error = ""
        if results.get(TARGET_US, {}).get("lost_frames"):
            try:
                with (
                    VethPair.create(netns=True) as veth,
                    pinned_simulator(config, veth.slave, veth.netns),
                ):
                    diagnosis = diagnose(config, veth.master, TARGET_US, diagnosis_seconds)
            except ToolError as e:
                diagnosis_error = str(e)[-300:]

    rows = []
    for loop_us in steps:
        thesis = _thesis(loop_us)
        r = results.get(loop_us)
        if r is None:
            rows.append(
                [loop_us, _khz(loop_us), *thesis, f"failed: {errors.get(loop_us, '?')}"] + [""] * 9
            )
            continue
        rtt, wake = r["rtt_us"], r["wake_latency_us"]
        c_rtt: dict[str, float] = (r.get("c_probe") or {}).get("rtt_us") or {}
        rows.append(
            [
                loop_us,
                _khz(loop_us),
                *thesis,
                r["lost_frames"],
                f"{100 * r['lost_frames'] / max(r['cycles'], 1):.2f} %",
                r["late_frames"],
                max(0, r["lost_frames"] - r["late_frames"]),
                r["wkc_errors"],
                r["cycles"],
                f"{fmt_us(rtt['p50'])} / {fmt_us(rtt['p99'])}",
                f"{fmt_us(wake['p99'])} / {fmt_us(wake['max'])}",
                " / ".join(fmt_us(c_rtt.get(p)) for p in ("p50", "p99", "p999", "max")),
                _share((r.get("c_probe") or {}).get("late_share")),
            ]
        )
    report.text(
        f"Skipped (lost) frames per EtherCAT loop time, {seconds:g} s per step. Thesis columns: "
        "Table 6.5 on the Laelaps II hardware (EtherLab, 240-byte frame); the native driver also "
        "had 0 skipped packets at 240 and 230 µs (4.35 kHz). ether_ros: 4 simulated legs, "
        "veth pair, master RT thread SCHED_FIFO 80 on CPU 1, simulator on CPU 0. Lost = no "
        "reply by the time the next cycle's frame is sent (what EtherLab counts as skipped); "
        "'of which late' = the reply came after that; 'never answered' = lost − late. "
        "After each step, `bench/c/rtt.c` sends the same "
        f"{IMAGE}-byte LRW through the same simulator at the same rate for {probe_seconds:g} s "
        "(CPU 1, SCHED_FIFO 80, no master): round trips longer than the loop time there are "
        "replies a master could not have had in time (their share is the last column, to compare "
        "with ether_ros's lost share). The master has stopped by then, so the "
        "slaves are back in INIT with SYNC0 off: the simulator does somewhat less per frame "
        "than in OP, and this floor is a little optimistic."
    )
    report.table(
        [
            "loop time (µs)",
            "kHz",
            "thesis: generic, no optimizations",
            "thesis: generic, optimized",
            "thesis: native",
            "ether_ros: lost",
            "lost share",
            "of which late",
            "never answered",
            "WKC errors",
            "cycles",
            "rtt p50 / p99 (µs)",
            "wake-up p99 / max (µs)",
            "C probe via the simulator: rtt p50 / p99 / p99.9 / max (µs)",
            "C probe: share later than the loop time",
        ],
        rows,
    )
    clean = [t for t in steps if t in results and results[t]["lost_frames"] == 0]
    best = min(clean) if clean else None
    at_target = results.get(TARGET_US)
    ok = at_target is not None and at_target["lost_frames"] == 0
    best_text = (
        f"{best} µs ({_khz(best)} kHz)" if best is not None else "none (every step lost frames)"
    )
    report.text(
        f"Shortest loop time with zero lost frames: {best_text}; thesis: 400 µs (2.5 kHz) with "
        "the generic driver (350 µs / 2.86 kHz after optimizations), 230 µs (4.35 kHz) with the "
        f"native driver. Target: zero lost frames at {TARGET_US} µs: "
        + (
            "met."
            if ok
            else "NOT met" + (f" ({errors[TARGET_US]})." if TARGET_US in errors else ".")
        )
    )
    if diagnosis is not None:
        report.text(_diagnosis_text(diagnosis, TARGET_US, diagnosis_seconds))
        report.value("diagnosis", diagnosis)
    elif diagnosis_error:
        report.text(f"The diagnosis run at {TARGET_US} µs failed: `{diagnosis_error}`")
    report.value("seconds_per_step", seconds)
    report.value("steps", {str(t): results[t] for t in results})
    report.value("errors", {str(t): e for t, e in errors.items()})
    report.value("shortest_clean_loop_us", best)
    report.value("target_met", ok)


def main(argv: list[str] | None = None) -> int:
    args = parse_worker_args("diagnose", argv)
    return diagnose_worker(args.config, args.interface, args.cycle_us, args.seconds, args.out)


if __name__ == "__main__":
    sys.exit(main())
