"""The simulator's frame path over real Ethernet (veth): how many cyclic frames it answers, the
CPU it needs for them, and the round trip it adds over a minimal C echo measured in the same run.

Per bus (4 and 16 Laelaps II legs), with the simulator process (`ether-ros sim`) in its own
network namespace on the far end of a veth pair:
1. baseline: the C echo on the same kind of veth pair, ping-pong round trips of the cyclic LRW
   frame (60 bytes of process data per leg);
2. the master (`ether_ros.master.Bus`) brings the simulated bus to OP and keeps its own cycle
   running (bus.cycle_us, 2.5 kHz); if that fails the simulator is measured in its power-on
   state and the report says so;
3. ping-pong round trips through the simulator → added median round trip (simulator − echo);
4. the C load generator sends the LRW paced at 20 kHz for a while and counts answers, while the
   simulator process's CPU time (all threads, and its busiest thread) is read from /proc.

Targets (docs/architecture.md): 4 legs at 20 kHz answered with < 25 % of one core; ≤ 10 µs
added median round trip.
"""

from __future__ import annotations

import statistics
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from baseline import (
    CpuSample,
    RttResult,
    ToolError,
    echo_responder,
    rtt_probe,
    simulator,
)
from ether_ros.testing.netns import VethPair
from report import BenchSkipped, Report, us

REPO = Path(__file__).resolve().parent.parent
BUSES = (("laelaps.yaml", 4), ("laelaps16.yaml", 16))
BYTES_PER_LEG = 38 + 22  # Table 4.1 outputs + Table 4.2 inputs
RATE_HZ = 20_000
# The simulator's frame thread runs SCHED_FIFO 70 (crates/sim/src/runner.rs): the C echo gets the
# same priority, and the probe/load generator a higher one so it paces and timestamps reliably.
RESPONDER_PRIORITY = 70
PROBE_PRIORITY = 75
CPU_TARGET = 0.25
ADDED_RTT_TARGET_NS = 10_000


@contextmanager
def master_in_op(config: Path, interface: str) -> Iterator[str]:
    """Bring the simulated bus to OP with the real master and keep it cycling; yields the state
    reached ("OP, master cycling at N µs" or why not)."""
    try:
        from ether_ros.master import Bus

        bus: Any = Bus.open(config, interface=interface)
    except Exception as e:  # the master is optional for this benchmark
        yield f"power-on state (master bring-up failed: {type(e).__name__}: {e})"
        return
    try:
        try:
            bus.start()
            state = f"OP, master cycling every {bus.config.bus.cycle_us} µs"
        except Exception as e:
            state = f"power-on state (master start failed: {type(e).__name__}: {e})"
        yield state
    finally:
        bus.close()


def _measure_bus(config: Path, legs: int, report: Report) -> dict[str, Any]:
    quick = report.quick
    rounds = 1 if quick else 5
    frames = 2_000 if quick else 4_000  # per round
    seconds = 2.0 if quick else 10.0
    size = legs * BYTES_PER_LEG

    def pingpong(interface: str) -> RttResult:
        return rtt_probe(interface, frames=frames, lrw_bytes=size, priority=PROBE_PRIORITY)

    def paced(interface: str) -> RttResult:
        return rtt_probe(
            interface, rate_hz=RATE_HZ, seconds=seconds, lrw_bytes=size, priority=PROBE_PRIORITY
        )

    with (
        VethPair.create(netns=True) as echo_veth,
        echo_responder(
            echo_veth.slave, netns=echo_veth.netns, priority=RESPONDER_PRIORITY
        ) as echo_proc,
        VethPair.create(netns=True) as veth,
        simulator(config, veth.slave, veth.netns) as sim,
        master_in_op(config, veth.master) as state,
    ):
        # Alternate echo and simulator rounds so slow drifts of the machine's load hit both.
        echo_rounds, sim_rounds = [], []
        for _ in range(rounds):
            echo_rounds.append(pingpong(echo_veth.master))
            sim_rounds.append(pingpong(veth.master))
        before = CpuSample.take(echo_proc.pid)
        paced(echo_veth.master)
        echo_cpu, _, _ = CpuSample.take(echo_proc.pid).share_since(before)
        before = CpuSample.take(sim.pid)
        sim_paced = paced(veth.master)
        cpu_total, busiest, cpu_thread = CpuSample.take(sim.pid).share_since(before)
        if sim.poll() is not None:
            raise ToolError(f"the simulator exited ({sim.returncode}) during the measurement")
    added = statistics.median(
        s.rtt_ns["p50"] - e.rtt_ns["p50"] for e, s in zip(echo_rounds, sim_rounds, strict=True)
    )
    return {
        "legs": legs,
        "lrw_bytes": size,
        "state": state,
        "rounds": rounds,
        "echo_p50": statistics.median(r.rtt_ns["p50"] for r in echo_rounds),
        "echo_p99": statistics.median(r.rtt_ns["p99"] for r in echo_rounds),
        "sim_p50": statistics.median(r.rtt_ns["p50"] for r in sim_rounds),
        "sim_p99": statistics.median(r.rtt_ns["p99"] for r in sim_rounds),
        "added_p50": added,
        "echo_rounds": echo_rounds,
        "sim_rounds": sim_rounds,
        "sim_paced": sim_paced,
        "cpu_process": cpu_total,
        "cpu_echo": echo_cpu,
        "cpu_busiest_thread": cpu_thread,
        "busiest_thread": busiest,
    }


def _as_json(r: RttResult) -> dict[str, Any]:
    return {"sent": r.sent, "answered": r.answered, "rate_hz": r.rate_hz, "rtt_ns": r.rtt_ns}


def run(report: Report) -> None:
    try:
        from ether_ros._native import SimNetwork  # noqa: F401
    except ImportError as e:
        raise BenchSkipped(
            f"ether_ros._native.SimNetwork is not available yet ({e}); the C baselines are in "
            "the `baseline` section"
        ) from None
    results = []
    for name, legs in BUSES:
        results.append(_measure_bus(REPO / "config" / name, legs, report))

    rows = []
    for r in results:
        paced = r["sim_paced"]
        answered_share = paced.answered / max(paced.sent, 1)
        rows.append(
            [
                r["legs"],
                r["lrw_bytes"],
                f"{paced.answered / paced.elapsed_s:.0f}",
                f"{100 * answered_share:.2f} %",
                f"{100 * r['cpu_process']:.1f} % ({100 * r['cpu_busiest_thread']:.1f} %)",
                f"{100 * r['cpu_echo']:.1f} %",
                us(r["echo_p50"]),
                us(r["sim_p50"]),
                us(r["added_p50"]),
                f"{r['sim_p50'] / max(r['echo_p50'], 1):.2f}",
                us(r["echo_p99"]),
                us(r["sim_p99"]),
                us(paced.rtt_ns["p50"]),
                us(paced.rtt_ns["p99"]),
            ]
        )
        report.value(
            f"legs_{r['legs']}",
            {
                "state": r["state"],
                "answered_hz": paced.answered / paced.elapsed_s,
                "answered_share": answered_share,
                "cpu_process": r["cpu_process"],
                "cpu_busiest_thread": r["cpu_busiest_thread"],
                "busiest_thread": r["busiest_thread"],
                "cpu_echo": r["cpu_echo"],
                "added_rtt_p50_ns": r["added_p50"],
                "echo_rounds": [_as_json(x) for x in r["echo_rounds"]],
                "sim_rounds": [_as_json(x) for x in r["sim_rounds"]],
                "sim_paced": _as_json(paced),
            },
        )
    states = "; ".join(f"{r['legs']} legs: {r['state']}" for r in results)
    report.text(
        f"LRW frame of 60 bytes per leg through a veth pair to `ether-ros sim` in its own "
        f"network namespace; C load generator paced at {RATE_HZ // 1000} kHz "
        f"({'2' if report.quick else '10'} s); round trips ping-pong, C echo and simulator "
        f"alternating over {results[0]['rounds']} rounds (medians of the rounds); probe SCHED_FIFO "
        f"{PROBE_PRIORITY}, simulator frame thread and C echo SCHED_FIFO {RESPONDER_PRIORITY}. "
        f"Slaves: {states}. "
        "CPU: simulator process, all threads (its busiest thread), share of one core; echo CPU: "
        "the C echo answering the same 20 kHz load (the kernel's share of the work). Round "
        "trips in µs; 'added' = median over rounds of (simulator p50 − C echo p50)."
    )
    report.table(
        [
            "legs", "bytes", "answered/s", "answered", "CPU", "echo CPU", "echo p50", "sim p50",
            "added p50", "ratio", "echo p99", "sim p99", "paced p50", "paced p99",
        ],
        rows,
    )  # fmt: skip
    four = results[0]
    added4 = four["added_p50"]
    ok_rate = four["sim_paced"].answered >= 0.999 * four["sim_paced"].sent
    ok_cpu = four["cpu_process"] < CPU_TARGET
    ok_rtt = added4 <= ADDED_RTT_TARGET_NS
    report.text(
        f"Targets (4 legs): 20 kHz answered {'met' if ok_rate else 'NOT met'}; CPU < 25 % of "
        f"one core {'met' if ok_cpu else 'NOT met'} ({100 * four['cpu_process']:.1f} %); added "
        f"median round trip ≤ 10 µs {'met' if ok_rtt else 'NOT met'} ({us(added4)} µs). "
        "CPU above the C echo's on the same load (the simulator's own work: ESC processing, "
        "device models at 10 kHz, SYNC0): "
        + ", ".join(
            f"{r['legs']} legs {100 * (r['cpu_process'] - r['cpu_echo']):.1f} %" for r in results
        )
        + "."
    )
    report.value("targets_met", {"rate": ok_rate, "cpu": ok_cpu, "added_rtt": ok_rtt})
