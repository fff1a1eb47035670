"""No starvation: valid joint commands from one client while N other publishers flood the node.

Setup as bench_ros_joints.py: ``RosRig`` on config/arm6.yaml (three two-axis CiA 402 drives on
the simulator, 1 kHz, DC), the node in its own process; joint ``JOINT`` enabled in csv, where a
setpoint becomes the drive's target velocity (0x60FF) in the next frame. A sender process
(``bench/ros_floor.py publish-joint``, its node the lease holder's writer) publishes one
JointState per value in two patterns of bench_ros.py: ``sparse`` (one every 20 ms, rclpy
``publish()`` of a message built then, from a normal thread) and ``controller`` (one every 1 ms
from a SCHED_FIFO 60 thread, serialized beforehand, as a real-time controller sends), noting
``time.time_ns()`` right before and after ``publish()``; a raw socket on the simulator's end of
the veth pair notes the kernel timestamp of the first frame carrying each value as the target.
Meanwhile ``FLOODERS`` processes (``ros_floor.py flood``), each its own DDS participant, publish
on ``joint_commands`` at 1 kHz each (a buggy controller each) or as fast as they can.

Rows, all in one run, the same sender against the same node (each node's ``no flood`` row is
the baseline of its flood rows):

- ``lease``: the node's lease is on (as shipped) and the flooders hold none: every flood
  message is refused on the native thread by its publisher GID before it is decoded;
- ``open``: a second rig with the lease off (a copy of arm6.yaml): the flooders send unknown
  joints (refused natively after a decode), values beyond the limits (valid in form: left to
  Python through the per-publisher fair queue, the excess refused natively) and garbage bytes
  (refused natively as undecodable).

The target (issue 19): valid commands on the wire within one cycle + 1 ms at p99 under the
flood, observed on the wire. On this 2-CPU VM the flooders at full speed are three busy
processes: they take the CPUs from every process at normal priority, the Python sender
included, so the ``sparse`` rows there measure the machine as much as the node; the
``controller`` rows (a real-time sender) measure the node's path.
"""

from __future__ import annotations

import contextlib
import json
import os
import time
from pathlib import Path

from bench_ros import (
    PATTERNS,
    CommandSender,
    WireSniffer,
    Worker,
    _cell,
    _percentile,
    _record,
    _wire_path,
    first_frames,
)
from bench_ros_joints import JOINT, _target_velocity
from report import BenchSkipped, Report, us

REPO = Path(__file__).resolve().parent.parent
CONFIG = REPO / "config" / "arm6.yaml"
FLOODERS = 3
SENDER_NODE = "/bench_command_sender"  # ros_floor.py publish's node: the lease holder's writer
TARGET_MARGIN_NS = 1_000_000
# (row, (flood topic, kind) of each flooder, messages/s per flooder (0: full speed), lease on)
NON_HOLDERS = (("joint_commands", "limit"),) * FLOODERS
INVALID = tuple(("joint_commands", kind) for kind in ("unknown", "limit", "garbage"))
VARIANTS = (
    ("lease: no flood", (), 0.0, True),
    ("lease: non-holders at 1 kHz each", NON_HOLDERS, 1000.0, True),
    ("lease: non-holders at full speed", NON_HOLDERS, 0.0, True),
    ("open: no flood", (), 0.0, False),
    ("open: invalid at 1 kHz each", INVALID, 1000.0, False),
    ("open: invalid at full speed", INVALID, 0.0, False),
)
BENCH_PATTERNS = tuple(p for p in PATTERNS if p[0] in ("sparse", "controller"))


def _rows(config: Path, variants: list[tuple[str, tuple, float, bool]], samples: int) -> dict:
    """Per variant and pattern: (timings, flood rate msg/s, node counters)."""
    from ether_ros.ros.rig import RosRig

    offset, scale, cycle = _target_velocity()
    out = {}
    with RosRig(config, client_options={"lease_writers": [SENDER_NODE]}) as rig:
        client = rig.client
        client.wait_for_node()
        for step in (lambda: client.axis_command("enable", [JOINT]),
                     lambda: client.set_mode("csv", [JOINT])):  # fmt: skip
            ok, message, _ = step()
            if not ok:
                raise BenchSkipped(f"{JOINT}: {message}")
        assert rig.veth is not None
        with contextlib.ExitStack() as stack:
            sender = CommandSender(rig.domain_id, ["publish-joint", JOINT, repr(scale)])
            stack.callback(sender.close)
            time.sleep(1.0)  # the lease's writer lookup picks the sender up
            for name, flood, rate, _lease in variants:
                flooders = []
                for topic, kind in flood:
                    args = ["flood", topic, kind, repr(rate)]
                    w = Worker(args, rig.domain_id, f"flooder {kind}")
                    flooders.append(w)
                    w.expect_ready()
                time.sleep(0.5)  # the flood is on
                sniffer = WireSniffer(rig.veth.slave, offset, "<i")
                sent = {}
                try:
                    for pattern, _, gap, kind in BENCH_PATTERNS:
                        sent[pattern] = sender.send(gap, samples, cycle / 1e9, kind)
                    time.sleep(0.1)
                finally:
                    sniffer.close()
                rate = 0.0
                for w in flooders:
                    w.send("stop")
                    report = json.loads(w.line(30))
                    rate += report["sent"] / max(report["seconds"], 1e-9)
                    w.close()
                all_sent = [s for row in sent.values() for s in row]
                frames = first_frames(all_sent, sniffer.changes)
                timings = {p: _wire_path(s, frames) for p, s in sent.items()}
                # Counters from after the flood (the diagnostics come every second).
                time.sleep(1.2)
                out[name] = (timings, rate, client.master_status(), sniffer)
                time.sleep(0.5)  # the node drains what the flood left queued
    return out


def run(report: Report) -> None:
    if os.geteuid() != 0:
        raise BenchSkipped("needs root (veth pairs)")
    import tempfile

    samples = 300 if report.quick else 1000
    _, _, cycle = _target_velocity()
    with tempfile.TemporaryDirectory(prefix="bench_flood_") as tmp:
        rows = _rows(CONFIG, [v for v in VARIANTS if v[3]], samples)
        from ether_ros.testing.configs import config_without_lease

        open_config = config_without_lease(CONFIG.name, Path(tmp))
        rows.update(_rows(open_config, [v for v in VARIANTS if not v[3]], samples))
    target = cycle + TARGET_MARGIN_NS
    report.text(
        f"### Valid joint commands under a flood (µs, p50 / p99 / max)\n\n"
        f"{samples} JointState messages per pattern for joint `{JOINT}` in csv, {us(cycle)} µs "
        f"cycle, from a sender process (the lease holder's writer) while {FLOODERS} other "
        "processes publish on `joint_commands` as fast as they can. *call → wire*: right before "
        "`publish()` → kernel timestamp of the first frame carrying the value as the drive's "
        f"target. Target: p99 ≤ one cycle + 1 ms = {us(target)} µs."
        + (
            " **Short run** (`--quick`) on the shared 2-CPU VM while other engineers' builds "
            "and tests ran: p99 and max are noisy."
            if report.quick
            else ""
        )
    )
    table = []
    for name, *_ in VARIANTS:
        timings, rate, counters, sniffer = rows[name]
        report.value(f"{name}_sniffer_dropped", sniffer.dropped)
        baseline = rows[name.split(":")[0] + ": no flood"][0]
        for pattern, descr, _, _ in BENCH_PATTERNS:
            t = timings[pattern].call_to_end
            r = timings[pattern].returned_to_end
            p99 = _percentile(t, 0.99)
            base = _percentile(baseline[pattern].call_to_end, 0.99)
            key = f"{name.replace(': ', '_').replace(' ', '_')}_{pattern}"
            _record(report, f"{key}_call_to_wire", t)
            _record(report, f"{key}_returned_to_wire", r)
            report.value(f"{key}_missed", timings[pattern].missed)
            table.append([name, f"{pattern} ({descr})", f"{len(t)} / {samples}", _cell(t),
                          _cell(r), f"{p99 / base:.2f}", "yes" if p99 <= target else "**no**",
                          f"{rate:,.0f}"])  # fmt: skip
        kinds = ("ros_joint_commands_refused", "ros_joint_commands_refused_lease")
        refused = sum(int(float(counters.get(k, "0"))) for k in kinds)
        key = name.replace(": ", "_").replace(" ", "_")
        report.value(f"{key}_flood_rate", rate)
        report.value(f"{key}_refused", refused)
    report.table(["node", "pattern", "seen", "call → wire", "returned → wire",
                  "call → wire p99 / no flood", "p99 within target",
                  "flood msg/s (all flooders)"], table)  # fmt: skip
