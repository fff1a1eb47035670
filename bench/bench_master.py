"""The whole master's cyclic round trip on real Ethernet, against pysoem (SOEM) and a C floor
driving the same kind of bus in the same run.

Setup: the simulator (`ether-ros sim`, 4 Laelaps II legs of `config/laelaps.yaml`) runs in its
own process, pinned to CPU 0 (`taskset -c 0`), in its own network namespace at the far end of a
veth pair. On the near end, in turns (rounds alternate so the shared VM's load hits all three):
1. our master: `ether-ros bench cycle` (bring-up to OP by `ether_ros.master.Bus`, then the engine's
   RT thread: SCHED_FIFO 80, memory locked, pinned to CPU 1 through `bus.realtime`), in both cycle
   orders: send_at_wake (IgH order, the default) and send_then_wait (SOEM order). Its round trip is
   the engine's `rtt` histogram: send instant → kernel receive timestamp of the reply;
2. pysoem (SOEM 1.1.x) bringing the same simulator to OP (`ether_ros.sim.proof.SoemBus`), then a
   Python loop `send_processdata(); receive_processdata()` every cycle, in a worker process with
   SCHED_FIFO 80, memory locked, pinned to CPU 1, garbage collector off. Its round trip is
   `time.perf_counter_ns()` around send + receive, taken in Python: it includes the Python calls
   into pysoem and SOEM's frame building and receive polling, which the engine's kernel-stamped
   figure does not;
3. the C floor: `bench/c/rtt.c` paced at the same rate with the same 240-byte LRW frame to the
   C echo (`bench/c/echo.c`, CPU 0, SCHED_FIFO 70 like the simulator's frame thread) over its
   own veth pair; clock_gettime around sendto/recv in C.

Target: our round trip ≤ 1.0 × pysoem's at p50 and at p99.
"""

from __future__ import annotations

import json
import os
import statistics
import subprocess
import sys
import tempfile
from contextlib import AbstractContextManager
from pathlib import Path
from typing import Any

BENCH = Path(__file__).resolve().parent
if str(BENCH) not in sys.path:  # when run as the pysoem worker script
    sys.path.insert(0, str(BENCH))

from baseline import (  # noqa: E402
    ToolError,
    echo_responder,
    ether_ros_exe,
    parse_worker_args,
    rtt_probe,
    run_worker,
    simulator,
)
from ether_ros.testing.netns import VethPair  # noqa: E402
from report import BenchSkipped, Report  # noqa: E402

REPO = BENCH.parent
CONFIG = REPO / "config" / "laelaps.yaml"
LEGS = 4
IMAGE = LEGS * (38 + 22)
CYCLE_US = 400
PRIORITY = 80
MASTER_CPU = 1
SIM_CPU = 0
RESPONDER_PRIORITY = 70  # the simulator's frame thread (crates/sim/src/runner.rs)
ORDERS = ("send_at_wake", "send_then_wait")
PCTS = (("p50", 50.0), ("p99", 99.0), ("p999", 99.9), ("max", 100.0))
RATIO_TARGET = 1.0


# ---------------------------------------------------------------------------------------------
# shared with bench_sweep


def write_config(directory: Path, cycle_order: str = "send_at_wake") -> Path:
    """A copy of config/laelaps.yaml with the cycle order and the real-time settings this
    benchmark states (SCHED_FIFO 80, memory locked, RT thread on CPU 1), ESI paths absolute."""
    import yaml

    doc = yaml.safe_load(CONFIG.read_text())
    bus = doc["bus"]
    bus["cycle_order"] = cycle_order
    bus["realtime"] = {
        **bus.get("realtime", {}),
        "policy": "fifo",
        "priority": PRIORITY,
        "cpu": MASTER_CPU,
        "lock_memory": True,
    }
    esi = doc.get("esi", [])
    doc["esi"] = [
        str((CONFIG.parent / p).resolve()) for p in ([esi] if isinstance(esi, str) else esi)
    ]
    path = directory / f"laelaps_{cycle_order}.yaml"
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return path


def pinned_simulator(
    config: Path, interface: str, netns: str | None, cpu: int = SIM_CPU
) -> AbstractContextManager[subprocess.Popen[str]]:
    """`ether-ros sim CONFIG` on ``interface`` (in ``netns``), all its threads on ``cpu``."""
    return simulator(config, interface, netns, cpu=cpu)


def bench_cycle(
    config: Path, interface: str, cycle_us: int, seconds: float, drift_frames: int | None = None
) -> dict[str, Any]:
    """Run `ether-ros bench cycle` and return its JSON result (raises ToolError on failure)."""
    with tempfile.TemporaryDirectory(prefix="bench_master_") as tmp:
        out = Path(tmp) / "cycle.json"
        cmd = [
            ether_ros_exe(), "bench", "cycle", str(config), "--interface", interface,
            "--cycle-us", str(cycle_us), "--seconds", f"{seconds:g}", "--json", str(out),
        ]  # fmt: skip
        if drift_frames is not None:
            cmd += ["--drift-frames", str(drift_frames)]
        try:
            r = subprocess.run(
                cmd, capture_output=True, text=True, check=False, timeout=seconds + 180
            )
        except subprocess.TimeoutExpired as e:
            raise ToolError(f"`ether-ros bench cycle --cycle-us {cycle_us}` hung") from e
        if r.returncode != 0 or not out.exists():
            detail = (r.stderr.strip() or r.stdout.strip())[-800:]
            raise ToolError(
                f"`ether-ros bench cycle --cycle-us {cycle_us}` failed ({r.returncode}): {detail}"
            )
        result: dict[str, Any] = json.loads(out.read_text())
        return result


def fmt_us(v: float | None) -> str:
    return "-" if v is None else f"{v:.1f}"


# ---------------------------------------------------------------------------------------------
# the pysoem worker (runs in its own process: `python bench/bench_master.py pysoem ...`)


def _percentiles_us(values_ns: list[int]) -> dict[str, float | None]:
    s = sorted(values_ns)
    if not s:
        return {k: None for k, _ in PCTS}
    return {k: s[min(len(s) - 1, int(p / 100 * (len(s) - 1) + 0.5))] / 1000 for k, p in PCTS}


def _lock_memory() -> None:
    import ctypes

    libc = ctypes.CDLL(None, use_errno=True)
    mcl_current, mcl_future = 1, 2
    if libc.mlockall(mcl_current | mcl_future) != 0:
        print(f"mlockall failed: errno {ctypes.get_errno()}", file=sys.stderr)


def pysoem_worker(config: Path, interface: str, cycle_us: int, seconds: float, out: Path) -> int:
    """Bring the bus to OP with pysoem, then time `send_processdata` + `receive_processdata`
    every ``cycle_us`` for ``seconds``; write percentiles and counters to ``out`` (JSON)."""
    import gc
    import time

    from ether_ros.config import load_bus_config
    from ether_ros.sim.proof import SoemBus

    cfg = load_bus_config(config)
    cfg.bus.cycle_us = cycle_us
    # Like the engine's send_then_wait: wait for the reply at most 3/4 of a cycle.
    t_open = time.monotonic()
    soem = SoemBus(cfg, interface, receive_timeout_us=cycle_us * 3 // 4)
    try:
        soem.scan()
        soem.configure()
        if not soem.request_op():
            raise SystemExit(f"pysoem: slaves did not reach OP: {soem.states()}")
        bringup_s = time.monotonic() - t_open
        os.sched_setaffinity(0, {MASTER_CPU})
        _lock_memory()
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(PRIORITY))
        master = soem.master
        expected = int(master.expected_wkc)
        period = cycle_us * 1000
        warmup = 200
        total = warmup + int(seconds * 1e6 / cycle_us)
        rtts: list[int] = []
        execs: list[int] = []
        lat: list[int] = []
        rtts_append, lat_append = rtts.append, lat.append
        lost = wkc_errors = overruns = 0
        clock = time.perf_counter_ns
        gc.disable()
        planned = clock() + period
        for n in range(total):
            delay = planned - clock()
            if delay > 0:
                time.sleep(delay / 1e9)
            t0 = clock()
            master.send_processdata()
            t_sent = clock()
            wkc = master.receive_processdata(soem.receive_timeout_us)
            t1 = clock()
            if n >= warmup:
                lat_append(t0 - planned)
                execs.append(t_sent - t0)
                if wkc <= 0:
                    lost += 1
                else:
                    rtts_append(t1 - t0)
                    if wkc != expected:
                        wkc_errors += 1
            planned += period
            behind = clock() - planned
            if behind > 0:  # woke so late the next cycle is due: skip, don't burst
                skipped = behind // period + 1
                planned += skipped * period
                if n >= warmup:
                    overruns += skipped
        gc.enable()
        os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
        result = {
            "cycles": total - warmup,
            "lost_frames": lost,
            "wkc_errors": wkc_errors,
            "overruns": overruns,
            "expected_wkc": expected,
            "bringup_s": bringup_s,
            "rtt_us": _percentiles_us(rtts),
            "exec_us": _percentiles_us(execs),
            "wake_latency_us": _percentiles_us([max(0, x) for x in lat]),
        }
        out.write_text(json.dumps(result, indent=2) + "\n")
    finally:
        soem.close()
    return 0


def run_pysoem(config: Path, interface: str, cycle_us: int, seconds: float) -> dict[str, Any]:
    args = [str(config), interface, str(cycle_us), f"{seconds:g}"]
    return run_worker(Path(__file__).resolve(), "pysoem", args, timeout=seconds + 120)


# ---------------------------------------------------------------------------------------------
# the benchmark


def _median(values: list[float | None]) -> float | None:
    vs = [v for v in values if v is not None]
    return statistics.median(vs) if vs else None


def _combine(rounds: list[dict[str, Any]], key: str) -> dict[str, float | None]:
    """Median over rounds of each percentile; the maximum of the maxima."""
    out = {p: _median([r[key][p] for r in rounds]) for p, _ in PCTS if p != "max"}
    maxima = [r[key]["max"] for r in rounds if r[key]["max"] is not None]
    out["max"] = max(maxima) if maxima else None
    return out


def _sum(rounds: list[dict[str, Any]], key: str) -> int:
    return sum(int(r.get(key, 0)) for r in rounds)


def run(report: Report) -> None:
    try:
        import pysoem  # noqa: F401

        import ether_ros._native  # noqa: F401
    except ImportError as e:
        raise BenchSkipped(f"needs ether_ros._native and pysoem: {e}") from None
    rounds, seconds = (1, 5.0) if report.quick else (3, 20.0)
    engine: dict[str, list[dict[str, Any]]] = {o: [] for o in ORDERS}
    soem: list[dict[str, Any]] = []
    floor: list[dict[str, Any]] = []
    with (
        tempfile.TemporaryDirectory(prefix="bench_master_") as tmp,
        VethPair.create(netns=True) as veth,
        VethPair.create(netns=True) as echo_veth,
        echo_responder(
            echo_veth.slave, netns=echo_veth.netns, priority=RESPONDER_PRIORITY, cpu=SIM_CPU
        ),
    ):
        configs = {o: write_config(Path(tmp), o) for o in ORDERS}
        with pinned_simulator(configs[ORDERS[0]], veth.slave, veth.netns) as sim:
            for _ in range(rounds):
                for order in ORDERS:
                    engine[order].append(
                        bench_cycle(configs[order], veth.master, CYCLE_US, seconds)
                    )
                soem.append(run_pysoem(configs[ORDERS[0]], veth.master, CYCLE_US, seconds))
                c = rtt_probe(
                    echo_veth.master, rate_hz=1e6 / CYCLE_US, seconds=seconds, lrw_bytes=IMAGE,
                    priority=PRIORITY, cpu=MASTER_CPU,
                )  # fmt: skip
                floor.append(
                    {
                        "cycles": c.sent,
                        "lost_frames": c.lost,
                        "rtt_us": {p: c.rtt_ns[p] / 1000 for p, _ in PCTS},
                    }
                )
                if sim.poll() is not None:
                    raise ToolError(f"the simulator exited ({sim.returncode})")

    rows = []
    summary: dict[str, dict[str, Any]] = {}

    def add_row(label: str, rs: list[dict[str, Any]]) -> None:
        rtt = _combine(rs, "rtt_us")
        summary[label] = {
            "rtt_us": rtt,
            "cycles": _sum(rs, "cycles"),
            "lost_frames": _sum(rs, "lost_frames"),
            "late_frames": _sum(rs, "late_frames"),
            "wkc_errors": _sum(rs, "wkc_errors"),
            "rounds": rs,
        }
        rows.append(
            [
                label,
                summary[label]["cycles"],
                summary[label]["lost_frames"],
                summary[label]["late_frames"] if label.startswith("ether_ros") else "-",
                summary[label]["wkc_errors"],
                *(fmt_us(rtt[p]) for p, _ in PCTS),
            ]
        )

    for order in ORDERS:
        add_row(f"ether_ros ({order})", engine[order])
    add_row("pysoem (Python loop)", soem)
    add_row("C probe → C echo (floor)", floor)
    report.text(
        f"4 Laelaps II legs ({IMAGE}-byte LRW + DC datagrams), cycle {CYCLE_US} µs; simulator "
        f"pinned to CPU {SIM_CPU} in a network namespace across a veth pair; masters SCHED_FIFO "
        f"{PRIORITY}, memory locked, on CPU {MASTER_CPU}; {rounds} round(s) of {seconds:g} s per "
        "master, alternating; percentiles are medians over rounds, max the largest. Round trips "
        "are not measured the same way: ether_ros = engine send instant → kernel receive "
        "timestamp; pysoem = `perf_counter_ns` in Python around `send_processdata()` + "
        "`receive_processdata()` (includes Python and SOEM overhead); C = `clock_gettime` around "
        "sendto/recv in `bench/c/rtt.c` to the C echo on its own veth pair (CPU 0, SCHED_FIFO "
        f"{RESPONDER_PRIORITY}). Lost = no reply in time (send_at_wake: before the next "
        "cycle's send; send_then_wait: "
        "within 3/4 of the cycle after the planned wake-up; pysoem: within 3/4 of the cycle "
        "after its send); 'of which late' = the reply did arrive, after that. Round trips in µs."
    )
    report.table(
        [
            "master",
            "cycles",
            "lost",
            "of which late",
            "WKC errors",
            "rtt p50",
            "rtt p99",
            "rtt p99.9",
            "rtt max",
        ],
        rows,
    )

    detail = []
    for order in ORDERS:
        ex = _combine(engine[order], "exec_us")
        w = _combine(engine[order], "wake_latency_us")
        detail.append(
            [
                f"ether_ros ({order})",
                " / ".join(fmt_us(ex[p]) for p, _ in PCTS),
                " / ".join(fmt_us(w[p]) for p, _ in PCTS),
                _sum(engine[order], "late_frames"),
            ]
        )
    w = _combine(soem, "wake_latency_us")
    detail.append(["pysoem (Python loop)", "-", " / ".join(fmt_us(w[p]) for p, _ in PCTS), "-"])
    report.text(
        "Engine execution time (wake-up → frame handed to the kernel) and wake-up latency, as "
        "reported by `ether-ros bench cycle --json`; pysoem's wake-up latency is Python's "
        "`time.sleep` overshoot, µs, p50 / p99 / p99.9 / max:"
    )
    report.table(["master", "execution", "wake-up latency", "late frames"], detail)

    ref = summary["pysoem (Python loop)"]["rtt_us"]
    verdicts = []
    for order in ORDERS:
        ours = summary[f"ether_ros ({order})"]["rtt_us"]
        ratios = {
            p: (ours[p] / ref[p] if ours[p] is not None and ref[p] else None)
            for p in ("p50", "p99")
        }
        ok = all(r is not None and r <= RATIO_TARGET for r in ratios.values())
        verdicts.append(
            f"- {order}: round trip / pysoem = {_ratio(ratios['p50'])} at p50, "
            f"{_ratio(ratios['p99'])} at p99 (target ≤ {RATIO_TARGET:g}): "
            f"{'met' if ok else 'NOT met'}"
        )
        summary[f"ether_ros ({order})"]["ratio_to_pysoem"] = ratios
    floor_rtt = summary["C probe → C echo (floor)"]["rtt_us"]
    for order in ORDERS:
        ours = summary[f"ether_ros ({order})"]["rtt_us"]
        if ours["p50"] is not None and floor_rtt["p50"]:
            verdicts.append(
                f"- {order}: round trip / C floor = {ours['p50'] / floor_rtt['p50']:.2f} at p50"
            )
    report.text("\n".join(verdicts))
    for label, s in summary.items():
        report.value(label, s)


def _ratio(r: float | None) -> str:
    return "-" if r is None else f"{r:.2f}"


def main(argv: list[str] | None = None) -> int:
    args = parse_worker_args("pysoem", argv)
    return pysoem_worker(args.config, args.interface, args.cycle_us, args.seconds, args.out)


if __name__ == "__main__":
    sys.exit(main())
