"""The links side by side: AF_PACKET (`packet`), AF_XDP (`xdp`), AF_XDP with busy polling, and
the C floor (bench/c/rtt.c on AF_PACKET), at 400, 100 and 50 µs loop times.

Setup as in bench_engine: the simulator (`ether-ros sim config/laelaps.yaml`, 4 Laelaps II legs)
in its own network namespace at the far end of a veth pair, the engine
(`ether_ros._native.Engine`) on the near end with the thesis's cyclic frame (DC datagrams and a
240-byte LRW), send_at_wake order, SCHED_FIFO 80, memory locked. The simulator runs on AF_PACKET
for the first three rows, so only the master's link differs; the last row puts the simulator on
xdp too (`ether-ros sim --link xdp`), XDP on both ends of the veth.

Per link and loop time, one window of the engine's RT thread: execution (wake-up → frame handed
to the kernel), wake-up latency, round trip, the share of cycles whose reply was lost (not there
by the next cycle), and the CPU the RT thread and the simulator used (share of one core). Every
row is also given as a ratio against `packet` at the same loop time, measured in the same run.
The C floor sends the same LRW at the same rate through a packet simulator: its round trip and
the share of replies later than the loop time (or lost) are what the path allows without our
master.

On veth the xdp link runs in copy mode: a transmitted frame still becomes an skb in the kernel
(generic AF_XDP transmit) and only the receive side skips the stack, so veth shows what the link
costs, not what a NIC with native (zero-copy) XDP gains.
"""

from __future__ import annotations

import threading
import time
from typing import Any

from baseline import CpuSample, ToolError, process_cpu_seconds, rtt_probe, simulator
from bench_engine import CONFIG, IMAGE, PRIORITY, _address_slaves, _run_engine
from ether_ros.testing.netns import VethPair
from report import BenchSkipped, Report, us

LOOP_TIMES_US = (400, 100, 50)
BUSY_POLL_US = 50
# (row name, engine link, busy poll µs, simulator link)
LINKS = (
    ("packet", "packet", 0, "packet"),
    ("xdp", "xdp", 0, "packet"),
    (f"xdp + busy poll {BUSY_POLL_US} µs", "xdp", BUSY_POLL_US, "packet"),
    ("xdp, simulator on xdp too", "xdp", 0, "xdp"),
)
RT_THREAD = "ether_ros-rt"


def _rt_thread_share(before: CpuSample, after: CpuSample) -> float:
    wall = max(after.wall - before.wall, 1e-9)
    return sum(
        (secs - before.threads.get(name, 0.0)) / wall
        for name, secs in after.threads.items()
        if name.endswith(f" {RT_THREAD}")
    )


def _measure_link(
    native: Any, engine_link: str, busy_poll_us: int, sim_link: str, window: float
) -> dict[int, dict[str, Any]]:
    import os

    out: dict[int, dict[str, Any]] = {}
    with (
        VethPair.create(netns=True) as veth,
        simulator(CONFIG, veth.slave, veth.netns, link=sim_link) as sim,
    ):
        engine = native.Engine.open_interface(veth.master, engine_link, busy_poll_us)
        try:
            _address_slaves(engine)
            for loop_us in LOOP_TIMES_US:
                engine.reset_stats()
                sim_before = process_cpu_seconds(sim.pid)
                cpu: list[CpuSample] = []

                def sample_rt(cpu: list[CpuSample] = cpu) -> None:
                    # The RT thread exists only while cyclic: sample inside the window.
                    time.sleep(0.2)
                    cpu.append(CpuSample.take(os.getpid()))
                    time.sleep(window - 0.4)
                    cpu.append(CpuSample.take(os.getpid()))

                sampler = threading.Thread(target=sample_rt)
                t0 = time.monotonic()
                sampler.start()
                _run_engine(engine, "send_at_wake", window, cycle_us=loop_us)
                sampler.join()
                wall = time.monotonic() - t0
                st = dict(engine.stats())
                st["rt_cpu"] = _rt_thread_share(cpu[0], cpu[1])
                st["sim_cpu"] = (process_cpu_seconds(sim.pid) - sim_before) / wall
                st["link"] = engine.link
                # The round trip from a send_then_wait window: the RT thread waits for the
                # reply, so its arrival is seen when it comes. (In send_at_wake the reply is read
                # at the next wake-up; AF_PACKET has the kernel's receive timestamp for it,
                # AF_XDP on veth has none, so its round trip would read as one whole cycle.)
                engine.reset_stats()
                _run_engine(engine, "send_then_wait", window / 2, cycle_us=loop_us)
                st["rtt_wait"] = dict(engine.stats())["rtt"]
                out[loop_us] = st
        finally:
            engine.close()
    return out


def _floor(window: float) -> dict[int, Any]:
    out = {}
    with VethPair.create(netns=True) as veth, simulator(CONFIG, veth.slave, veth.netns):
        for loop_us in LOOP_TIMES_US:
            out[loop_us] = rtt_probe(
                veth.master,
                rate_hz=1e6 / loop_us,
                seconds=window,
                lrw_bytes=IMAGE,
                priority=PRIORITY,
                over_us=loop_us,
            )
    return out


def _ratio(value: float, base: float) -> str:
    return f"{value / base:.2f}" if base > 0 else "–"


def run(report: Report) -> None:
    try:
        import ether_ros._native as native
    except ImportError as e:
        raise BenchSkipped(f"ether_ros._native is not built: {e}") from e
    window = 2.0 if report.quick else 5.0
    results: dict[str, dict[int, dict[str, Any]]] = {}
    for name, engine_link, busy, sim_link in LINKS:
        try:
            results[name] = _measure_link(native, engine_link, busy, sim_link, window)
        except (OSError, ToolError, RuntimeError) as e:
            if engine_link == "packet":
                raise
            report.text(f"- {name}: not measured here ({e})")
    floor = _floor(window)

    rows = []
    for loop_us in LOOP_TIMES_US:
        base = results["packet"][loop_us]
        for name, st in results.items():
            st = st[loop_us]
            ex, lat, rtt = st["exec"], st["wake_latency"], st["rtt_wait"]
            lost = st["lost_frames"] / max(st["cycles"], 1)
            base_lost = base["lost_frames"] / max(base["cycles"], 1)
            rows.append(
                [
                    loop_us,
                    name,
                    st["cycles"],
                    f"{100 * lost:.2f} %",
                    f"{us(ex['p50'])} / {us(ex['p99'])}",
                    f"{us(lat['p50'])} / {us(lat['p99'])}",
                    f"{us(rtt['p50'])} / {us(rtt['p99'])}",
                    f"{100 * st['rt_cpu']:.1f} % / {100 * st['sim_cpu']:.1f} %",
                    " / ".join(
                        [
                            _ratio(ex["p50"], base["exec"]["p50"]),
                            _ratio(lat["p50"], base["wake_latency"]["p50"]),
                            _ratio(rtt["p50"], base["rtt_wait"]["p50"]),
                            _ratio(lost, base_lost),
                            _ratio(st["rt_cpu"], base["rt_cpu"]),
                        ]
                    ),
                ]
            )
            report.value(f"{name}@{loop_us}", st)
        f = floor[loop_us]
        late = (f.lost + f.over) / max(f.sent, 1)
        rows.append(
            [
                loop_us,
                "C floor (rtt.c, AF_PACKET)",
                f.sent,
                f"{100 * late:.2f} % (late or lost)",
                "–",
                "–",
                f"{us(f.rtt_ns['p50'])} / {us(f.rtt_ns['p99'])}",
                "–",
                f"– / – / {_ratio(f.rtt_ns['p50'], base['rtt_wait']['p50'])} / – / –",
            ]
        )
        report.value(
            f"floor@{loop_us}",
            {"sent": f.sent, "lost": f.lost, "over": f.over, "rtt_ns": f.rtt_ns},
        )
    report.text(
        f"4 legs ({IMAGE}-byte LRW + DC datagrams), send_at_wake, SCHED_FIFO {PRIORITY}, memory "
        f"locked, not pinned; one {window:.0f} s send_at_wake window per link and loop time for "
        f"execution, latency, losses and CPU, then {window / 2:.1f} s of send_then_wait for the "
        "round trip (see the module doc); the simulator runs on AF_PACKET except in the last row. "
        "The round trips "
        "are not alike: packet's is stamped by the kernel when the reply reaches the socket, "
        "xdp's when the RT thread has read it (AF_XDP on veth has no receive timestamp), so "
        "xdp's includes the thread's wake-up from ppoll. CPU: the engine's RT thread / the whole "
        "simulator process, as a share of one core. Ratios are against `packet` at the same "
        "loop time (below 1: better)."
    )
    report.table(
        [
            "loop (µs)",
            "link",
            "cycles",
            "lost",
            "execution p50 / p99 (µs)",
            "wake-up latency p50 / p99 (µs)",
            "round trip (send_then_wait) p50 / p99 (µs)",
            "CPU RT thread / simulator",
            "ratio vs packet: exec / wake / rtt / lost / RT CPU",
        ],
        rows,
    )
