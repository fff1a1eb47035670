"""The master against slave count: buses of 4, 16, 64 and 128 slaves (the first N of
`config/line128.yaml`: Laelaps II legs, two-axis CiA 402 drives and generic I/O boxes in a
repeating pattern, DC), for ether_ros and for pysoem (SOEM) on the same simulated bus.

Setup per size: the simulator (`ether-ros sim`) in its own process, pinned to CPU 0, in its own
network namespace across a veth pair. On the near end, in turn:
1. ether_ros: `ether-ros bench cycle` at 1 ms (bring-up to OP timed from `Bus.open` to OP, then
   the engine's RT thread: SCHED_FIFO 80, memory locked, CPU 1, send_at_wake): execution time
   (wake-up → the last frame of the cycle handed to the kernel), round trip (the slowest frame of
   the cycle: send → kernel receive timestamp), lost frames, frames per cycle;
2. pysoem: the worker of bench_master.py (bring-up timed from `Master.open` to OP, then a
   Python loop `send_processdata()` / `receive_processdata()` at 1 ms, SCHED_FIFO 80, CPU 1).
   Its "execution" is `send_processdata()`, its round trip send + receive, both timed in Python;
3. the simulator's CPU: its process's user + system time over the ether_ros run (bring-up
   included), as a share of one core;
4. the shortest cycle: `ether-ros bench cycle` at 1000, 500, 250 and 125 µs, a short run each,
   next to the C probe (`bench/c/rtt.c`) through the same simulator at the same rate with one
   LRW as large as the image (capped at one frame) counting replies later than the cycle — the
   path's own floor. The shortest cycle is the shortest whose lost share is no higher than the
   probe's late share, with every longer cycle passing too.

Same-run baselines: pysoem and the C probe run on the same simulator in the same run.
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path
from typing import Any

BENCH = Path(__file__).resolve().parent
if str(BENCH) not in sys.path:
    sys.path.insert(0, str(BENCH))

from baseline import CpuSample, ToolError, rtt_probe  # noqa: E402
from bench_master import (  # noqa: E402
    MASTER_CPU,
    PRIORITY,
    bench_cycle,
    fmt_us,
    pinned_simulator,
    run_pysoem,
)
from ether_ros.testing.netns import VethPair  # noqa: E402
from report import BenchSkipped, Report  # noqa: E402

REPO = BENCH.parent
LINE = REPO / "config" / "line128.yaml"
SIZES = (4, 16, 64, 128)
CYCLE_US = 1000
SWEEP_US = (1000, 500, 250, 125)
MAX_LRW = 1400  # the C probe's largest LRW (one frame per cycle)


def write_line(directory: Path, n: int) -> tuple[Path, int]:
    """The first ``n`` slaves of config/line128.yaml with this benchmark's real-time settings
    (SCHED_FIFO 80, memory locked, CPU 1) and absolute ESI paths; and the image size."""
    import yaml

    from ether_ros.config import load_bus_config

    doc = yaml.safe_load(LINE.read_text())
    doc["slaves"] = doc["slaves"][:n]
    doc["bus"]["name"] = f"line{n}"
    doc["bus"]["realtime"] = {"policy": "fifo", "priority": PRIORITY, "cpu": MASTER_CPU,
                              "lock_memory": True}  # fmt: skip
    doc["esi"] = [str((LINE.parent / p).resolve()) for p in doc["esi"]]
    path = directory / f"line{n}.yaml"
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    cfg = load_bus_config(path)
    image = sum(s.layout.output_bytes + s.layout.input_bytes for s in cfg.slaves)
    return path, image


def _measure(config: Path, image: int, seconds: float, sweep_seconds: float) -> dict[str, Any]:
    out: dict[str, Any] = {"image_bytes": image}
    with (
        VethPair.create(netns=True) as veth,
        pinned_simulator(config, veth.slave, veth.netns) as sim,
    ):
        before = CpuSample.take(sim.pid)
        out["ether_ros"] = bench_cycle(config, veth.master, CYCLE_US, seconds)
        share, _thread, _ = CpuSample.take(sim.pid).share_since(before)
        out["sim_cpu_share"] = share
        try:
            out["pysoem"] = run_pysoem(config, veth.master, CYCLE_US, seconds)
        except ToolError as e:
            # First line: how the worker ended (exit code or signal); last: its last words.
            lines = str(e).splitlines() or ["failed"]
            out["pysoem_error"] = (
                f"pysoem: {lines[0][:80]} … {lines[-1][-120:]}" if len(lines) > 1 else lines[0]
            )
        sweep = {}
        for loop_us in SWEEP_US:
            try:
                r = bench_cycle(config, veth.master, loop_us, sweep_seconds)
            except ToolError as e:
                sweep[loop_us] = {"error": str(e).splitlines()[-1][:200]}
                continue
            probe = rtt_probe(
                veth.master, rate_hz=1e6 / loop_us, seconds=max(1.0, sweep_seconds / 2),
                lrw_bytes=min(image, MAX_LRW), priority=PRIORITY, cpu=MASTER_CPU,
                over_us=loop_us,
            )  # fmt: skip
            sweep[loop_us] = {
                "cycles": r["cycles"],
                "lost_frames": r["lost_frames"],
                "frames": r.get("frames", 1),
                "lost_share": r["lost_frames"] / max(r["cycles"] * max(r.get("frames", 1), 1), 1),
                "probe_late_share": (probe.over + probe.lost) / max(probe.sent, 1),
            }
        out["sweep"] = sweep
        if sim.poll() is not None:
            raise ToolError(f"the simulator exited ({sim.returncode})")
    return out


def _shortest(sweep: dict[int, dict[str, Any]]) -> str:
    """The shortest cycle that passes with every longer one passing too."""
    best = None
    for us in SWEEP_US:
        r = sweep.get(us, {"error": "not run"})
        if "error" in r or r["lost_share"] > r["probe_late_share"]:
            break
        best = us
    return f"{best} µs" if best is not None else f"none (≥ {SWEEP_US[0]} µs)"


def _pct(r: dict[str, Any] | None, key: str, p: str) -> str:
    if not r:
        return "-"
    return fmt_us((r.get(key) or {}).get(p))


def run(report: Report) -> None:
    try:
        import ether_ros._native  # noqa: F401
    except ImportError as e:
        raise BenchSkipped(f"ether_ros._native is not built: {e}") from None
    seconds, sweep_seconds = (3.0, 1.5) if report.quick else (10.0, 3.0)
    results: dict[int, dict[str, Any]] = {}
    with tempfile.TemporaryDirectory(prefix="bench_scale_") as tmp:
        for n in SIZES:
            print(f"[scale] {n} slaves", flush=True)
            config, image = write_line(Path(tmp), n)
            try:
                results[n] = _measure(config, image, seconds, sweep_seconds)
            except ToolError as e:
                results[n] = {"error": str(e).splitlines()[-1][:300], "image_bytes": image}
    rows = []
    for n in SIZES:
        r = results[n]
        if "error" in r:
            rows.append([n, r["image_bytes"], f"failed: {r['error']}"] + [""] * 9)
            continue
        ours, soem = r["ether_ros"], r.get("pysoem")
        rows.append(
            [
                n,
                r["image_bytes"],
                ours.get("frames", "?"),
                f"{ours['bringup_s']:.2f} / {soem['bringup_s']:.2f}"
                if soem
                else f"{ours['bringup_s']:.2f} / -",
                f"{_pct(ours, 'exec_us', 'p50')} / {_pct(ours, 'exec_us', 'p99')}",
                f"{_pct(soem, 'exec_us', 'p50')} / {_pct(soem, 'exec_us', 'p99')}",
                f"{_pct(ours, 'rtt_us', 'p50')} / {_pct(ours, 'rtt_us', 'p99')}",
                f"{_pct(soem, 'rtt_us', 'p50')} / {_pct(soem, 'rtt_us', 'p99')}",
                f"{ours['lost_frames']} / {soem['lost_frames'] if soem else '-'}",
                f"{100 * r['sim_cpu_share']:.0f} %",
                _shortest(r["sweep"]),
                r.get("pysoem_error", ""),
            ]
        )
    report.text(
        f"Buses of N slaves (the first N of config/line128.yaml), cycle {CYCLE_US} µs, "
        f"{seconds:g} s per master; simulator pinned to CPU 0 in a network namespace across a "
        "veth pair; masters "
        f"SCHED_FIFO {PRIORITY} on CPU {MASTER_CPU}. ether_ros / pysoem in each cell; times in µs "
        "(bring-up in s): execution = wake-up → last frame handed to the kernel (pysoem: its "
        "`send_processdata()` in Python); round trip = ether_ros: the slowest frame of the cycle, "
        "send → kernel receive timestamp; pysoem: send + receive in Python. Simulator CPU = its "
        "process over the ether_ros run (bring-up included), share of one core. Shortest cycle: "
        f"`bench cycle` at {', '.join(str(u) for u in SWEEP_US)} µs, {sweep_seconds:g} s each; "
        "the shortest whose lost share (of frames), and that of every longer step, is no higher "
        "than the C probe's share of replies later than the cycle through the same simulator "
        f"(one frame per cycle, capped at {MAX_LRW} bytes). The machine is a shared 2-core VM "
        "under load: runs are short and noisy."
    )
    report.table(
        [
            "slaves",
            "image bytes",
            "frames/cycle",
            "bring-up s",
            "exec p50/p99 (ours)",
            "exec p50/p99 (pysoem)",
            "rtt p50/p99 (ours)",
            "rtt p50/p99 (pysoem)",
            "lost (ours / pysoem)",
            "sim CPU",
            "shortest cycle",
            "note",
        ],
        rows,
    )
    sweep_rows = []
    for n in SIZES:
        for us, s in (results[n].get("sweep") or {}).items():
            if "error" in s:
                sweep_rows.append([n, us, f"failed: {s['error']}", "", "", ""])
                continue
            sweep_rows.append(
                [
                    n,
                    us,
                    s["cycles"],
                    s["lost_frames"],
                    f"{100 * s['lost_share']:.2f} %",
                    f"{100 * s['probe_late_share']:.2f} %",
                ]
            )
    report.text("The sweep behind the shortest cycle:")
    report.table(
        ["slaves", "cycle µs", "cycles", "lost frames", "lost share", "C probe late share"],
        sweep_rows,
    )
    for n in SIZES:
        report.value(f"line{n}", results[n])
