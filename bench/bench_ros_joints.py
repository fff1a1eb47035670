"""CiA 402 joints over ROS 2: how long a ``joint_commands`` message (sensor_msgs/JointState,
as ``topic_based_ros2_control`` publishes it) takes to become the drive's target on the wire,
measured as the ``pdo_listener`` benchmark (bench_ros.py) measures writes, with the DDS floor
of the same run.

Setup: ``RosRig`` on config/arm6.yaml (three two-axis CiA 402 drives on the simulator, 1 kHz,
DC), the node in its own process serving ``joint_commands`` on its native command path. The
joint ``JOINT`` is enabled and switched to cyclic synchronous velocity (csv), where a setpoint
becomes the drive's target velocity (0x60FF) in the next frame as it is (in csp the engine
interpolates positions between setpoints, so there is no single frame that "carries" a
command). A sender process (``bench/ros_floor.py publish-joint``) publishes one JointState per
value — a new raw velocity each time, unique within the run — in the patterns of bench_ros.py,
noting ``time.time_ns()`` right before and after ``publish()``; a raw socket on the simulator's
end of the veth pair notes the kernel timestamp of the first frame whose LRW carries each value
in the joint's target velocity. The floor: the same sender publishes the same messages, in
another ROS domain, to a minimal Python wait-set subscriber (``ros_floor.py subscribe joints``),
interleaved with the node's rows.
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
    Timings,
    WireSniffer,
    Worker,
    _cell,
    _floor_path,
    _mean,
    _percentile,
    _record,
    _wire_path,
    first_frames,
)
from report import BenchSkipped, Report, us

REPO = Path(__file__).resolve().parent.parent
CONFIG = REPO / "config" / "arm6.yaml"
JOINT = "elbow"
FLOOR_DOMAIN_OFFSET = 7  # RosRig's is 0; bench_ros uses 3..6


def _target_velocity() -> tuple[int, float, int]:
    """(byte offset of JOINT's target velocity in the output image, its velocity scale, the
    cycle in ns)."""
    from ether_ros.config import load_bus_config

    cfg = load_bus_config(CONFIG)
    spec = next(a for a in cfg.axis_specs() if a.name == JOINT)
    offset = 0
    for s in sorted(cfg.slaves, key=lambda s: s.position or 0):
        if s.name == spec.slave:
            var = spec.variables["target_velocity"]
            return (
                offset + var.bit_offset // 8,
                float(spec.config.velocity_scale),
                int(cfg.bus.cycle_us) * 1000,
            )
        offset += s.layout.output_bytes
    raise KeyError(spec.slave)


def _measure(samples: int) -> tuple[dict[str, Timings], dict[str, Timings], WireSniffer, int]:
    from ether_ros.ros.rig import RosRig, domain_for

    offset, scale, cycle = _target_velocity()
    sender = ["publish-joint", JOINT, repr(scale)]
    sent_node, sent_floor = {}, {}
    with RosRig(CONFIG) as rig, contextlib.ExitStack() as stack:
        client = rig.client
        client.wait_for_node()
        for step in (lambda: client.axis_command("enable", [JOINT]),
                     lambda: client.set_mode("csv", [JOINT])):  # fmt: skip
            ok, message, _ = step()
            if not ok:
                raise BenchSkipped(f"{JOINT}: {message}")
        assert rig.veth is not None
        sniffer = WireSniffer(rig.veth.slave, offset, "<i")
        stack.callback(sniffer.close)
        floor_domain = domain_for(os.getpid(), FLOOR_DOMAIN_OFFSET)
        subscriber = Worker(["subscribe", "joints"], floor_domain, "the floor subscriber")
        stack.callback(subscriber.close)
        subscriber.expect_ready()
        to_floor = CommandSender(floor_domain, sender)
        stack.callback(to_floor.close)
        to_node = CommandSender(rig.domain_id, sender)
        stack.callback(to_node.close)
        for pattern, _, gap, kind in PATTERNS:  # interleaved: the same load for both
            sent_floor[pattern] = to_floor.send(gap, samples, cycle / 1e9, kind)
            sent_node[pattern] = to_node.send(gap, samples, cycle / 1e9, kind)
        time.sleep(0.1)
        sniffer.close()
        to_floor.end()
        woken = {int(k): v for k, v in json.loads(subscriber.line(30)).items()}
        counters = client.master_status()
    all_sent = [s for sent in sent_node.values() for s in sent]
    frames = first_frames(all_sent, sniffer.changes)
    node = {k: _wire_path(sent, frames) for k, sent in sent_node.items()}
    floor = {k: _floor_path(sent, woken) for k, sent in sent_floor.items()}
    deferred = int(float(counters.get("ros_joint_commands_deferred", "0")))
    return node, floor, sniffer, deferred


def run(report: Report) -> None:
    if os.geteuid() != 0:
        raise BenchSkipped("needs root (veth pairs)")
    samples = 300 if report.quick else 1000
    node, floor, sniffer, deferred = _measure(samples)
    if not any(p.call_to_end for p in node.values()):
        raise BenchSkipped("no joint command was seen on the wire")
    _, _, cycle = _target_velocity()
    descr = {name: d for name, d, _, _ in PATTERNS}
    report.text(
        f"### joint_commands → target on the wire (µs, p50 / p99 / max)\n\n"
        f"{samples} JointState messages per row for joint `{JOINT}` in csv (each a new target "
        f"velocity), {us(cycle)} µs cycle, the node serving `joint_commands` on its native "
        "command path; *call → wire*: right before `publish()` → kernel timestamp of the first "
        "frame carrying the value as the drive's target; *returned → wire*: from `publish()` "
        "returning. *floor returned → woken*: the same sender and messages to a minimal Python "
        "subscriber in the same run (DDS delivery and a wake-up, no node, no EtherCAT); "
        "*floor returned → received*: the middleware's own delivery. *node share (mean)*: "
        "node *returned → wire* − floor *returned → received* − half a cycle (the average wait "
        "for the next frame), means without the slowest 1 %: a rough guide that can come out "
        "negative."
        + (
            " **Short run** (`--quick`) on the shared 2-CPU VM while other engineers' builds "
            "and tests ran: the p99 and max columns are noisy."
            if report.quick
            else ""
        )
    )
    rows = []
    for pattern, _, _, _ in PATTERNS:
        n, f = node[pattern], floor[pattern]
        share = _mean(n.returned_to_end) - _mean(f.returned_to_received) - cycle / 2
        rows.append([f"{pattern} ({descr[pattern]})", len(n.call_to_end), _cell(n.call_to_end),
                     _cell(n.returned_to_end), _cell(f.returned_to_end),
                     _cell(f.returned_to_received), us(share)])  # fmt: skip
        _record(report, f"node_{pattern}_call_to_wire", n.call_to_end)
        _record(report, f"node_{pattern}_returned_to_wire", n.returned_to_end)
        _record(report, f"floor_{pattern}_returned_to_woken", f.returned_to_end)
        _record(report, f"floor_{pattern}_returned_to_received", f.returned_to_received)
        report.value(f"node_{pattern}_share_mean_ns", share)
        report.value(f"node_{pattern}_missed", n.missed)
        report.value(f"node_{pattern}_superseded", n.superseded)
    report.table(["pattern", "samples", "call → wire", "returned → wire",
                  "floor returned → woken", "floor returned → received", "node share (mean)"],
                 rows)  # fmt: skip
    sparse = node["sparse"].call_to_end
    report.text(
        f"Sparse call → wire p50 {us(_percentile(sparse, 0.5))} µs, p99 "
        f"{us(_percentile(sparse, 0.99))} µs against a {us(cycle)} µs cycle. Commands left to "
        f"Python by the native path: {deferred} (expected 0: every command here is valid). "
        f"Values never seen on the wire: {sum(p.missed for p in node.values())}; replaced "
        f"before a frame carried them: {sum(p.superseded for p in node.values())}; the "
        f"sniffer dropped {sniffer.dropped} of {sniffer.frames + sniffer.dropped} frames."
    )
    report.value("deferred", deferred)
