"""The cost of the CiA 402 axis stage in the engine's cycle: execution time with 6 and with 32
axes against the same bus without axes, in the same run.

Setup as in bench_engine: the simulator (`ether-ros sim config/laelaps.yaml`) in its own
network namespace across a veth pair, slaves addressed but without FMMUs, so the LRW passes
through unchanged. The LRW carries 32 drives' process data (32 × (14 output + 20 input bytes),
the default PDOs of devices/servo_drive.xml) in every variant, so frame and link work are the
same; only the number of axes in the plan changes (0, 6, 32). The input bytes of a pass-through
frame keep what the image started with, so each drive's statusword says Operation Enabled in
cyclic synchronous position mode: every axis runs the full stage each cycle (statusword
decoding, command slot check, interpolation, limits, targets, status publication), and a
Python thread sends every axis a position setpoint at 100 Hz, as a controller would.

1 kHz (the arm's rate), SCHED_FIFO 80, memory locked; variants take turns in short windows so
that they see the same (shared, changing) machine load. Execution = wake-up → frame handed to
the kernel; the axis stage runs before the frame is filled, so its cost is all inside it.
"""

from __future__ import annotations

import math
import time
from pathlib import Path
from typing import Any

from baseline import ToolError, one_lrw_plan, simulator
from bench_engine import address_slaves
from ether_ros.testing.netns import VethPair
from report import BenchSkipped, Report, us

REPO = Path(__file__).resolve().parent.parent
CONFIG = REPO / "config" / "laelaps.yaml"
CYCLE_US = 1000
PRIORITY = 80
DRIVES = 32
OUT_BYTES, IN_BYTES = 14, 20  # default RxPDO 0x1600 / TxPDO 0x1A00 of ServoDrive1
OUTPUTS = DRIVES * OUT_BYTES
IMAGE = DRIVES * (OUT_BYTES + IN_BYTES)
VARIANTS = (0, 6, 32)
OPERATION_ENABLED = 0x0027
CSP = 8


def _axis(n: int) -> Any:
    """Axis ``n`` as a ``_native.AxisPlan`` (every field given: the engine type has no
    defaults for what the configuration decides)."""
    from ether_ros import _native

    out, inp = n * OUT_BYTES, OUTPUTS + n * IN_BYTES
    return _native.AxisPlan(
        name=f"joint_{n}",
        map=_native.AxisMap(
            controlword=out,
            mode=out + 2,
            target_position=out + 4,
            target_velocity=out + 8,
            target_torque=out + 12,
            statusword=inp,
            mode_display=inp + 2,
            position=inp + 4,
            velocity=inp + 8,
            torque=inp + 12,
            error_code=inp + 14,
            following_error=inp + 16,
        ),
        mode="csp",
        position_scale=4.8e-5,
        position_offset=0.0,
        velocity_scale=4.8e-5,
        torque_scale=0.01,
        position_min=-3.0,
        position_max=3.0,
        velocity_max=3.0,
        torque_max=8.0,
        deceleration=math.inf,
        mode_change_velocity="actual",
        restart="manual",
        following_error_window=0.05,
        on_stop="quick_stop",
        fault_reset="auto",
        fault_retries=3,
        fault_backoff_ns=100_000_000,
    )


def _initial_image() -> bytes:
    """Outputs zero; every drive's inputs: statusword Operation Enabled, mode display csp."""
    image = bytearray(IMAGE)
    for n in range(DRIVES):
        inp = OUTPUTS + n * IN_BYTES
        image[inp : inp + 2] = OPERATION_ENABLED.to_bytes(2, "little")
        image[inp + 2] = CSP
    return bytes(image)


def _plan(axes: int) -> Any:
    return one_lrw_plan(
        cycle_us=CYCLE_US,
        order="send_at_wake",
        image=_initial_image(),
        output_bytes=OUTPUTS,
        sync0_shift_ns=100_000,
        priority=PRIORITY,
        axes=[_axis(n) for n in range(axes)],
    )


def _run(engine: Any, axes: int, seconds: float) -> dict[str, Any]:
    """One window: start with `axes` axes, enable them, command them at 100 Hz; the stats of
    the window."""
    engine.start_cyclic(_plan(axes))
    try:
        time.sleep(0.05)
        engine.reset_stats()
        for i in range(axes):
            engine.axis_enable(i, True)
        start = time.monotonic()
        while (t := time.monotonic() - start) < seconds:
            for i in range(axes):
                engine.axis_setpoint(i, "position", 0.5 * math.sin(2 * math.pi * 0.5 * t))
            engine.feed_watchdog()
            engine.drain_samples()
            time.sleep(0.01)
        if axes:
            st = engine.axis_status(axes - 1)
            if st["state"] != "operation_enabled" or st["command_seq"] == 0:
                raise ToolError(f"the axes did not run: {st}")
        return dict(engine.stats())
    finally:
        engine.stop_cyclic()


def _pool(windows: list[dict[str, Any]], key: str) -> dict[str, float]:
    """Percentiles over windows: the median of each window's value (a shared VM's load changes
    between windows; the median keeps one bad window from deciding)."""
    vals = {p: sorted(w[key][p] for w in windows) for p in ("p50", "p99", "max")}
    return {p: v[len(v) // 2] for p, v in vals.items()} | {
        "cycles": sum(w["cycles"] for w in windows)
    }


def run(report: Report) -> None:
    try:
        import ether_ros._native as _native
    except ImportError as e:
        raise BenchSkipped(f"ether_ros._native is not built: {e}") from e
    rounds, window = (2, 1.0) if report.quick else (5, 3.0)
    results: dict[int, list[dict[str, Any]]] = {n: [] for n in VARIANTS}
    with VethPair.create(netns=True) as veth, simulator(CONFIG, veth.slave, veth.netns):
        engine = _native.Engine.open_interface(veth.master)
        try:
            address_slaves(engine)
            for _ in range(rounds):
                for n in VARIANTS:
                    results[n].append(_run(engine, n, window))
        finally:
            engine.close()

    base = _pool(results[0], "exec")
    rows = []
    for n in VARIANTS:
        ex, snd = _pool(results[n], "exec"), _pool(results[n], "send")
        own = ex["p50"] - snd["p50"]
        rows.append(
            [
                n,
                ex["cycles"],
                f"{us(ex['p50'])} / {us(ex['p99'])} / {us(ex['max'])}",
                f"{us(snd['p50'])} / {us(snd['p99'])}",
                f"{us(own)}",
                f"{ex['p50'] / base['p50']:.2f} / {ex['p99'] / base['p99']:.2f}",
            ]
        )
        report.value(f"axes_{n}", {"exec": ex, "send": snd})
    report.text(
        f"LRW of {IMAGE} bytes (32 drives' default PDOs) + DC datagrams, cycle {CYCLE_US} µs, "
        f"SCHED_FIFO {PRIORITY}, memory locked; {rounds} rounds of {window:g} s per variant, "
        "variants alternating; every axis in Operation Enabled (csp) with a position setpoint "
        "every 10 ms. Percentiles: median over the rounds. Simulator in a network namespace "
        "across a veth pair."
    )
    report.table(
        [
            "axes",
            "cycles",
            "execution p50 / p99 / max (µs)",
            "of which send() p50 / p99 (µs)",
            "execution − send p50 (µs)",
            "execution vs 0 axes, p50 / p99",
        ],
        rows,
    )
