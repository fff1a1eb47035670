"""The native joint_commands path (crates/commands/src/joints.rs, ``_native.JointTable``)
against the Python one (``bridge.resolve_joint_command``), the reference: over thousands of
JointState messages (known, unknown and repeated joints, every array empty, one per name or of
another length, values inside and beyond the limits, NaN and infinities, axes in position,
velocity and torque modes), whatever the native path applies by itself Python accepts too, with
the same setpoints, and every message Python accepts takes the native path. Then bytes from the
wire: every mutation of a valid message is resolved or refused with ValueError, never a crash.
The thread itself is exercised by tests/unit/test_ros_joints_inprocess.py."""

from __future__ import annotations

import math
import random
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from rclpy.serialization import serialize_message
from sensor_msgs.msg import JointState
from test_native_commands import mutation_outcomes

from ether_ros.config import load_bus_config
from ether_ros.errors import EtherRosError
from ether_ros.master.bus import Bus
from ether_ros.ros import bridge
from ether_ros.ros.native_commands import joint_table
from ether_ros.sim.network import build_network

# netns: the bus runs with its configuration's realtime section (SCHED_FIFO, locked memory).
pytestmark = [pytest.mark.ros, pytest.mark.netns]

REPO = Path(__file__).resolve().parents[2]
VALUES = (0.0, 0.1, -0.5, 1.9, 2.0, 2.4, -2.5, 3.0, 3.05, 3.2, 4.5, 9.0, math.nan, math.inf)


@pytest.fixture(scope="module")
def axes() -> Iterator[dict[str, Any]]:
    cfg = load_bus_config(REPO / "config" / "arm6.yaml")
    with Bus.open(cfg, link=build_network(cfg)) as bus:
        bus.start()
        axes = bridge.bus_axes(bus)
        axes["wrist_2"].set_mode("csv")
        axes["wrist_3"].set_mode("cst")
        yield axes
        bus.stop()


def python_resolution(axes: dict[str, Any], msg: JointState) -> list[tuple[int, str, float]] | None:
    try:
        commands = bridge.resolve_joint_command(
            axes, list(msg.name), list(msg.position), list(msg.velocity), list(msg.effort)
        )
    except EtherRosError:
        return None
    return [(axis.index, kind, value) for axis, kind, value in commands]


def messages(names: list[str], seed: int, count: int) -> Iterator[JointState]:
    rng = random.Random(seed)
    pool = [*names, "nope", ""]
    for _ in range(count):
        n = rng.choice((0, 1, 1, 2, 3, 6))
        chosen = (
            [rng.choice(pool) for _ in range(n)]
            if rng.random() < 0.3
            else rng.sample(names, min(n, len(names)))
        )
        msg = JointState()
        msg.name = chosen
        for array in ("position", "velocity", "effort"):
            shape = rng.random()
            size = len(chosen) if shape < 0.7 else (0 if shape < 0.9 else len(chosen) + 1)
            setattr(msg, array, [rng.choice(VALUES) * rng.choice((1, -1)) for _ in range(size)])
        yield msg


def test_the_native_resolver_applies_exactly_what_python_accepts(axes: dict[str, Any]) -> None:
    table = joint_table(axes)
    applied = refused = 0
    for msg in messages(list(axes), seed=1, count=6000):
        native = table.resolve(serialize_message(msg))
        python = python_resolution(axes, msg)
        assert native == python, msg  # applied with the same setpoints, or left to Python
        if python is None:
            refused += 1
        else:
            applied += 1
    assert applied > 500 and refused > 500


def python_refusal(axes: dict[str, Any], msg: JointState) -> str | None:
    try:
        bridge.resolve_joint_command(
            axes, list(msg.name), list(msg.position), list(msg.velocity), list(msg.effort)
        )
    except EtherRosError as exc:
        return str(exc)
    return None


def test_the_native_path_refuses_only_what_python_refuses_in_its_words(
    axes: dict[str, Any],
) -> None:
    """What the native path refuses by itself (so a flood of it never reaches the queue for
    Python) Python refuses too, with the very same message."""
    table = joint_table(axes)
    refused_natively = 0
    for msg in messages(list(axes), seed=2, count=6000):
        native = table.refusal(serialize_message(msg))
        if native is not None:
            refused_natively += 1
            assert native == python_refusal(axes, msg), msg
    assert refused_natively > 500  # unknown and repeated joints, arrays of the wrong length
    # Names Python would quote with escapes are left to Python.
    odd = JointState(name=["it's"], position=[0.0])
    assert table.refusal(serialize_message(odd)) is None
    assert python_refusal(axes, odd) is not None


def test_a_mode_change_reaches_the_table(axes: dict[str, Any]) -> None:
    table = joint_table(axes)
    msg = JointState(name=["wrist_2"], velocity=[0.5])
    assert table.resolve(serialize_message(msg)) == [(axes["wrist_2"].index, "velocity", 0.5)]
    table.set_kind(list(axes).index("wrist_2"), None)
    assert table.resolve(serialize_message(msg)) is None
    with pytest.raises(ValueError, match="unknown setpoint kind 'speed'"):
        table.set_kind(0, "speed")


def test_garbage_never_crashes_the_resolver(axes: dict[str, Any]) -> None:
    """Bytes from the wire are untrusted: every mutation of a valid message is decoded and
    resolved like any message, or refused with ValueError naming what is wrong."""
    table = joint_table(axes)
    good = serialize_message(
        JointState(name=["elbow", "wrist_1"], position=[0.1, 0.2], velocity=[], effort=[])
    )
    outcomes = mutation_outcomes(table.resolve, good, seed=5, count=4000)
    assert all(outcomes.values()), outcomes
