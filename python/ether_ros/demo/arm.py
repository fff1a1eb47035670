"""``ether-ros demo arm``: the 6-axis arm of config/arm6.yaml (three two-axis CiA 402 drives on
the simulator) moved by a joint trajectory sent over ROS 2.

1. A veth pair, the simulator's end in a network namespace of its own; the simulator
   (``ether-ros sim``, the ``cia402`` drive model: 50:1 joints, position/velocity cascade) in its
   own process.
2. The node (``ether-ros run``) on the other end, in its own process: OP, 1 kHz with DC.
3. This process is a plain rclpy client: it enables every axis (service ``enable``), publishes
   one ``trajectory_msgs/JointTrajectory`` for all six joints on ``joint_trajectory`` (a swing
   out and back per joint over four seconds, starting at a stamp half a second ahead) and
   records ``joint_states``.
4. A summary: per joint the RMS and largest tracking error (measured position against the
   trajectory, interpolated as the engine does: as ROS 2's JointTrajectoryController, from the
   state at the trajectory's arrival to its first point), where it ended, then the bus's
   counters and loop timing from the node's diagnostics.

Run: ``ether-ros demo arm`` (root; about 20 s).
"""

from __future__ import annotations

import math
import os
import sys
import threading
import time
from pathlib import Path
from typing import Any

from sensor_msgs.msg import JointState

from ether_ros.demo.trot import bus_lines
from ether_ros.ros.joints import estimated_velocities
from ether_ros.ros.rig import RosRig

REPO = Path(__file__).resolve().parents[3]
ARM_CONFIG = REPO / "config" / "arm6.yaml"
# Swing amplitude per joint (rad) and the waypoint times (s): out, back, the other way, back.
AMPLITUDE = {"shoulder_pan": 0.6, "shoulder_lift": -0.4, "elbow": 0.5, "wrist_1": -0.5,
             "wrist_2": 0.7, "wrist_3": -0.7}  # fmt: skip
SHAPE = ((1.0, 1.0), (2.0, 0.0), (3.0, -1.0), (4.0, 0.0))
START_AHEAD_S = 0.5
TRACKED_RAD = 0.05  # a joint whose RMS error stays below this follows its trajectory


def hermite(times: list[float], positions: list[float], t: float) -> float:
    """The position at ``t`` on the cubic Hermite curve through the points, with the velocities
    the node gives waypoints without them (``joints.estimated_velocities``), as the engine
    interpolates it; before the first point its position, after the last the last."""
    if t <= times[0]:
        return positions[0]
    if t >= times[-1]:
        return positions[-1]
    v = estimated_velocities(times, positions)
    i = max(k for k in range(len(times) - 1) if times[k] <= t)
    h = times[i + 1] - times[i]
    s = (t - times[i]) / h
    return (
        (2 * s**3 - 3 * s**2 + 1) * positions[i]
        + (s**3 - 2 * s**2 + s) * h * v[i]
        + (-2 * s**3 + 3 * s**2) * positions[i + 1]
        + (s**3 - s**2) * h * v[i + 1]
    )


class JointRecorder:
    """joint_states samples: (stamp in wall-clock s, {joint: position})."""

    def __init__(self) -> None:
        self.samples: list[tuple[float, dict[str, float]]] = []
        self._lock = threading.Lock()

    def on_joint_state(self, msg: JointState) -> None:
        t = msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9
        with self._lock:
            self.samples.append((t, dict(zip(msg.name, msg.position, strict=False))))

    def since(self, t0: float) -> list[tuple[float, dict[str, float]]]:
        with self._lock:
            return [s for s in self.samples if s[0] >= t0]


def tracking(
    recorder: JointRecorder, start: float, initial: dict[str, float], sent: float
) -> dict[str, tuple[float, float, float]]:
    """Per joint: (RMS error, largest error, final position) over the trajectory. The engine
    goes from the state at the trajectory's arrival (``sent``, wall clock, give or take the
    message's way to the node) to the first point, as JointTrajectoryController does; a start
    stamp ahead does not hold the joints still until then."""
    end = start + SHAPE[-1][0]
    samples = [s for s in recorder.since(sent) if s[0] <= end + 0.5]
    out = {}
    for joint, amplitude in AMPLITUDE.items():
        times = [sent - start] + [t for t, _ in SHAPE]
        positions = [initial[joint]] + [initial[joint] + amplitude * k for _, k in SHAPE]
        errors = [
            values[joint] - hermite(times, positions, t - start)
            for t, values in samples
            if joint in values
        ]
        rms = math.sqrt(sum(e * e for e in errors) / len(errors)) if errors else math.nan
        largest = max((abs(e) for e in errors), default=math.nan)
        final = samples[-1][1].get(joint, math.nan) if samples else math.nan
        out[joint] = (rms, largest, final)
    return out


def run_arm_demo(config: Path = ARM_CONFIG) -> int:
    if os.geteuid() != 0:
        print("ether-ros demo arm: needs root (it creates a veth pair)", file=sys.stderr)
        return 2
    started = time.monotonic()
    recorder = JointRecorder()
    print(f"ether-ros demo arm: simulator + node on a veth pair ({config.name}) ...", flush=True)
    options = {"on_joint_state": recorder.on_joint_state}
    with RosRig(config, netns=True, client_options=options) as rig:
        client = rig.client
        state = client.wait_for_node()
        ok, message, _ = client.axis_command("enable")
        print(f"node {client.target} {state}; enable: {message}", flush=True)
        if not ok:
            return 1

        # A joint_states message with every joint (one whose drive's inputs are stale is left
        # out of it).
        def complete(latest: Any) -> Any:
            js = latest.joint_state
            return js if js is not None and set(AMPLITUDE) <= set(js.name) else None

        msg = client.wait_for(complete, 5.0)
        assert msg is not None  # wait_for returns a truthy value
        initial = dict(zip(msg.name, msg.position, strict=True))
        joints = list(AMPLITUDE)
        points = [(t, [initial[j] + AMPLITUDE[j] * k for j in joints]) for t, k in SHAPE]
        start = time.time() + START_AHEAD_S
        before = len(client.joint_results)
        sent = time.time()
        client.publish_trajectory(joints, points, start=start)
        client.wait_for(lambda _l: len(client.joint_results) > before, 5.0)
        answer = client.joint_results[before]
        print(answer.message, flush=True)
        if not answer.success:
            return 1
        time.sleep(max(0.0, start + SHAPE[-1][0] + 0.7 - time.time()))
        client.wait_for(lambda latest: latest.counts.get("diagnostics", 0) >= 2, 3.0)
        result = tracking(recorder, start, initial, sent)
        lines = ["Tracking (joint_states against the trajectory)"]
        for joint, (rms, largest, final) in result.items():
            lines.append(
                f"  {joint:<14} RMS error {rms:7.4f} rad  max {largest:7.4f} rad  "
                f"(swing {abs(AMPLITUDE[joint]):.2f} rad, ended at {final:+.4f} rad)"
            )
        lines.extend(bus_lines(client))
    print("\n".join(lines))
    print(f"demo finished in {time.monotonic() - started:.0f} s", flush=True)
    tracked = all(rms < TRACKED_RAD for rms, _, _ in result.values())
    return 0 if tracked else 1
