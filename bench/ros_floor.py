"""Worker processes of the ROS benchmark (bench_ros.py), each a fresh interpreter so that nothing
else in the benchmark process (the rig's ROS client, the wire sniffer) shares its GIL or caches:

- ``publish``: the command sender. Publishes ``WriteVariable`` on ``pdo_listener`` (or, as
  ``publish-joint JOINT SCALE``, a ``sensor_msgs/JointState`` velocity for JOINT on
  ``joint_commands``: the raw value ``joint_value(seq)`` × SCALE, ``header.frame_id`` the
  sequence number) in the pattern
  it is told on stdin (one line ``GAP_S COUNT FIRST_SEQ DITHER_S [SENDER]``: COUNT values, one
  every GAP_S seconds on an absolute schedule, each moved later by a random 0..DITHER_S; SENDER
  ``python`` builds each message when it is due and calls ``publish()`` from a normal thread,
  ``controller`` publishes messages serialized beforehand from a SCHED_FIFO 60 thread, as a
  real-time controller would) and answers
  with one JSON line per pattern: for every value
  ``[seq, value, t_construct, t_publish, t_returned]`` — ``time.time_ns()`` before building
  the message, right before ``publish()`` and right after it returns. ``end`` sends a message
  with variable ``__end__`` (tells the floor subscriber to stop); ``quit`` or EOF ends.
- ``subscribe [joints]``: the DDS floor. A minimal low-level rclpy wait set on ``pdo_listener``
  (``joint_commands``); stamps
  ``time.time_ns()`` right after ``rcl_wait`` returns (before taking) and after the take, and
  keeps the middleware's ``received_timestamp`` of the sample (when DDS in this process had
  it, before this thread woke); on ``__end__`` prints
  ``{request_id: [t_woken, t_taken, t_received]}`` as JSON and exits.

- ``flood TOPIC KIND [RATE]``: a flooding publisher (bench_flood.py). Once its writer matched a
  reader it prints ``ready`` and publishes one message, serialized once, as fast as it can (or
  RATE messages a second, on an absolute schedule)
  (``joint_commands``: KIND ``unknown`` — a joint the bus does not have —, ``limit`` — a
  position far beyond the elbow's limits —, ``garbage`` — bytes no JointState decodes to;
  ``pdo_listener``: ``text`` — a write of an unknown variable — or ``garbage``) until a line
  ``stop`` (or EOF), then prints ``{"sent": N, "seconds": S}``.

Both print ``ready`` once set up (the publisher: once its writer matched a reader). The ROS
domain comes from the environment (``ROS_DOMAIN_ID``, set by the benchmark).

    python bench/ros_floor.py publish SLAVE VARIABLE
    python bench/ros_floor.py publish-joint JOINT SCALE
    python bench/ros_floor.py subscribe [joints]
    python bench/ros_floor.py flood TOPIC KIND [RATE]
"""

from __future__ import annotations

import argparse
import json
import os
import random
import sys
import threading
import time
from pathlib import Path
from typing import Any

END = "__end__"
CONFIG = Path(__file__).resolve().parent.parent / "config" / "laelaps.yaml"  # as bench_ros.py
CONTROLLER_PRIORITY = 60  # below the engine's RT thread (80), above the node's command path (50)
MATCH_TIMEOUT_S = 30.0


class Messages:
    """What a sender publishes: WriteVariable writes, or JointState joint commands."""

    def __init__(self, joints: bool, target: str, arg: str) -> None:
        from ether_ros_msgs.msg import WriteVariable
        from sensor_msgs.msg import JointState

        self.joints = joints
        self.target, self.arg = target, arg
        self.type: Any = JointState if joints else WriteVariable
        self.topic = "joint_commands" if joints else "pdo_listener"

    def value(self, seq: int) -> int:
        return joint_value(seq) if self.joints else command_value(seq)

    def make(self, seq: int) -> Any:
        if self.joints:
            return joint_command(self.target, float(self.arg), seq)
        return command(self.target, self.arg, seq)

    def end(self) -> Any:
        if self.joints:
            msg = self.type(name=[self.target], velocity=[0.0])
            msg.header.frame_id = END
            return msg
        return self.type(slave=self.target, variable=END)

    def key(self, msg: Any) -> int | None:
        """The sequence number a floor subscriber files a message under (None: the end)."""
        if self.joints:
            return None if msg.header.frame_id == END else int(msg.header.frame_id)
        return None if msg.variable == END else int(msg.request_id)


def publish(messages: Messages) -> int:
    import rclpy
    from rclpy.serialization import serialize_message

    from ether_ros.config import load_bus_config
    from ether_ros.ros.native_commands import housekeeping_cpus
    from ether_ros.ros.node import QOS_COMMANDS

    rt_cpu = load_bus_config(CONFIG).bus.realtime.cpu
    rclpy.init()
    node = rclpy.create_node("bench_command_sender")
    pub = node.create_publisher(messages.type, messages.topic, QOS_COMMANDS)
    deadline = time.monotonic() + MATCH_TIMEOUT_S
    while pub.get_subscription_count() < 1:
        if time.monotonic() > deadline:
            print("no subscriber matched", file=sys.stderr, flush=True)
            return 1
        time.sleep(0.05)
    time.sleep(0.5)  # let discovery traffic settle before anything is timed
    print("ready", flush=True)
    for line in sys.stdin:
        words = line.split()
        if not words or words[0] == "quit":
            break
        if words[0] == "end":
            pub.publish(messages.end())
            print("[]", flush=True)
            continue
        gap_ns, count, first = int(float(words[0]) * 1e9), int(words[1]), int(words[2])
        dither_ns = int(float(words[3]) * 1e9) if len(words) > 3 else 0
        controller = len(words) > 4 and words[4] == "controller"
        everywhere = set(os.sched_getaffinity(0))
        housekeeping = housekeeping_cpus(rt_cpu)
        rng = random.Random(first)  # the same offsets for the same command
        stamps: list[list[int]] = []
        ready: list[bytes] = []
        if controller:
            ready = [serialize_message(messages.make(first + i)) for i in range(count)]
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(CONTROLLER_PRIORITY))
            # A controller runs on the housekeeping CPUs, not on the EtherCAT RT thread's.
            os.sched_setaffinity(0, housekeeping or everywhere)
        start = time.monotonic_ns() + gap_ns
        for i in range(count):
            # An absolute schedule: a late send does not push the later ones back. Each send is
            # moved by a random part of the dither (the receiver's cycle), so that its phase to
            # that cycle is uniform rather than fixed by when the pattern started.
            due = start + i * gap_ns + int(rng.random() * dither_ns)
            delay = due - time.monotonic_ns()
            if delay > 0:
                time.sleep(delay / 1e9)
            seq = first + i
            value = messages.value(seq)
            t_construct = time.time_ns()
            msg: Any = ready[i] if controller else messages.make(seq)
            t_publish = time.time_ns()
            pub.publish(msg)  # bytes: published as they are (rclpy's publish_raw)
            t_returned = time.time_ns()
            stamps.append([seq, value, t_construct, t_publish, t_returned])
        if controller:
            os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
            os.sched_setaffinity(0, everywhere)
        print(json.dumps(stamps), flush=True)
    node.destroy_node()
    rclpy.try_shutdown()
    return 0


def command(slave: str, variable: str, seq: int) -> Any:
    from ether_ros_msgs.msg import WriteVariable

    msg = WriteVariable(slave=slave, variable=variable, value=float(command_value(seq)))
    msg.request_id = seq
    return msg


def command_value(seq: int) -> int:
    """The value sent as command number ``seq``: distinct for the first 20000 numbers (7919 is
    prime to 20000), within int16, and never 0 or a small number a config might start with."""
    return 1000 + (seq * 7919) % 20000


def joint_value(seq: int) -> int:
    """The raw velocity sent as joint command ``seq``: distinct like ``command_value``, its sign
    alternating so that the joint does not wander off."""
    return command_value(seq) * (1 if seq % 2 else -1)


def joint_command(joint: str, scale: float, seq: int) -> Any:
    from sensor_msgs.msg import JointState

    msg = JointState(name=[joint], velocity=[joint_value(seq) * scale])
    msg.header.frame_id = str(seq)
    return msg


def subscribe(messages: Messages) -> int:
    import rclpy
    from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy

    from ether_ros.ros.node import QOS_COMMANDS

    rclpy.init()
    node = rclpy.create_node("bench_floor_subscriber")
    # The callback is never called: nothing spins this node; the loop below takes directly.
    sub = node.create_subscription(messages.type, messages.topic, lambda _m: None, QOS_COMMANDS)
    wait_set = _rclpy.WaitSet(1, 0, 0, 0, 0, 0, node.context.handle)
    seen: dict[int, list[int]] = {}
    print("ready", flush=True)
    while True:
        wait_set.clear_entities()
        wait_set.add_subscription(sub.handle)
        wait_set.wait(200_000_000)
        t_woken = time.time_ns()
        taken = sub.handle.take_message(messages.type, False)
        t_taken = time.time_ns()
        if taken is None:
            continue
        msg, info = taken[0], taken[1]
        key = messages.key(msg)
        if key is None:
            break
        # received_timestamp: when the middleware in this process received the sample (the
        # system clock, as time.time_ns()), before this thread was woken.
        t_received = int(info.get("received_timestamp") or 0)
        seen.setdefault(key, [t_woken, t_taken, t_received])
    print(json.dumps(seen), flush=True)
    node.destroy_node()
    rclpy.try_shutdown()
    return 0


FLOOD_KINDS = {
    "joint_commands": ("unknown", "limit", "garbage"),
    "pdo_listener": ("text", "garbage"),
}


def flood_message(topic: str, kind: str) -> tuple[Any, bytes]:
    """(message type, serialized message) a flooder publishes."""
    from ether_ros_msgs.msg import WriteVariable
    from rclpy.serialization import serialize_message
    from sensor_msgs.msg import JointState

    garbage = b"\x00\x01\x00\x00" + b"\xff" * 12  # CDR_LE, then a length nothing fits
    if topic == "joint_commands":
        if kind == "unknown":
            return JointState, serialize_message(JointState(name=["no_such"], position=[0.0]))
        if kind == "limit":
            return JointState, serialize_message(JointState(name=["elbow"], position=[1e6]))
        return JointState, garbage
    if kind == "text":
        return WriteVariable, serialize_message(WriteVariable(slave="x", variable="no", text="1"))
    return WriteVariable, garbage


def flood(topic: str, kind: str, rate: float = 0.0) -> int:
    import rclpy

    from ether_ros.ros.node import QOS_COMMANDS

    rclpy.init()
    node = rclpy.create_node(f"bench_flood_{os.getpid()}")
    msg_type, data = flood_message(topic, kind)
    pub = node.create_publisher(msg_type, topic, QOS_COMMANDS)
    deadline = time.monotonic() + MATCH_TIMEOUT_S
    while pub.get_subscription_count() < 1:
        if time.monotonic() > deadline:
            print("no subscriber matched", file=sys.stderr, flush=True)
            return 1
        time.sleep(0.05)
    stop = False

    def watch() -> None:
        nonlocal stop
        for line in sys.stdin:
            if line.strip() in ("stop", "quit"):
                break
        stop = True

    threading.Thread(target=watch, daemon=True).start()
    print("ready", flush=True)
    sent, start = 0, time.monotonic()
    gap = 1.0 / rate if rate > 0 else 0.0
    while not stop:
        pub.publish(data)
        sent += 1
        if gap:
            delay = start + sent * gap - time.monotonic()
            if delay > 0:
                time.sleep(delay)
    print(json.dumps({"sent": sent, "seconds": time.monotonic() - start}), flush=True)
    node.destroy_node()
    rclpy.try_shutdown()
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="worker of the ROS benchmark (internal)")
    sub = parser.add_subparsers(dest="cmd", required=True)
    p = sub.add_parser("publish")
    p.add_argument("slave")
    p.add_argument("variable")
    p = sub.add_parser("publish-joint")
    p.add_argument("joint")
    p.add_argument("scale")
    p = sub.add_parser("subscribe")
    p.add_argument("kind", nargs="?", choices=("writes", "joints"), default="writes")
    p = sub.add_parser("flood")
    p.add_argument("topic", choices=tuple(FLOOD_KINDS))
    p.add_argument("kind", choices=sorted({k for ks in FLOOD_KINDS.values() for k in ks}))
    p.add_argument("rate", nargs="?", type=float, default=0.0, help="messages/s (0: max)")
    args = parser.parse_args(argv)
    if args.cmd == "flood":
        if args.kind not in FLOOD_KINDS[args.topic]:
            parser.error(f"{args.topic} floods take {', '.join(FLOOD_KINDS[args.topic])}")
        return flood(args.topic, args.kind, args.rate)
    if args.cmd == "publish":
        return publish(Messages(False, args.slave, args.variable))
    if args.cmd == "publish-joint":
        return publish(Messages(True, args.joint, args.scale))
    return subscribe(Messages(args.kind == "joints", "", ""))


if __name__ == "__main__":
    sys.exit(main())
