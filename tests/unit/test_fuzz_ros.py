"""Fuzzing the ROS boundary (hypothesis, derandomized): whatever a DDS participant publishes on
``pdo_listener``, ``joint_commands`` or ``joint_trajectory`` or asks of ``write_variables``,
the node's checks answer with its own error naming what is wrong, or accept a write that fits
its variable — never another exception. Raw bytes are checked by the native decoder before
rclpy reads them.

``FUZZ_EXAMPLES`` (default 200) sets the run; ``make fuzz`` runs many more.
"""

from __future__ import annotations

import math
import os
from types import SimpleNamespace
from typing import Any

import pytest
from ether_ros_msgs.msg import WriteVariable
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from rclpy.serialization import serialize_message
from sensor_msgs.msg import JointState
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

from bus_specs import spec_of
from ether_ros.errors import EtherRosError, MessageError
from ether_ros.ros import bridge, joints
from ether_ros.ros.native_commands import checked_message
from ether_ros.ros.values import check_value

pytestmark = [pytest.mark.ros]

FUZZ = settings(
    max_examples=int(os.environ.get("FUZZ_EXAMPLES", "200")),
    derandomize=True,
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow],
)
SPEC = spec_of("laelaps.yaml")
NAMES = [v.name for v in SPEC.slaves[0].outputs] + [v.address for v in SPEC.slaves[0].outputs]
SLAVES = [s.name for s in SPEC.slaves]

texts = st.one_of(st.sampled_from(["", "0x10", "true", "1.5", "-3", "1e3"]), st.text(max_size=30))
names = st.one_of(st.sampled_from(NAMES), st.text(max_size=30))
floats = st.one_of(st.floats(), st.integers(-(2**40), 2**40).map(float))


@FUZZ
@given(
    slave=st.one_of(st.just(""), st.sampled_from(SLAVES), st.text(max_size=20)),
    position=st.integers(-(2**31), 2**31 - 1),
    all_slaves=st.booleans(),
    variable=names,
    value=floats,
    text=texts,
)
def test_any_write_request_is_resolved_or_refused_with_a_message_error(
    slave: str, position: int, all_slaves: bool, variable: str, value: float, text: str
) -> None:
    try:
        writes = bridge.resolve_write(SPEC, slave, position, all_slaves, variable, value, text)
    except MessageError as exc:
        assert str(exc)
        assert exc.field in ("slave", "position", "all_slaves", "variable", "value", "text"), exc
        return
    assert writes
    assert not (all_slaves and (slave or position >= 0)), "one slave or all, never both"
    for _slave, var, checked in writes:
        assert check_value(checked, var) == checked
        assert math.isfinite(checked)


def _serialized() -> st.SearchStrategy[bytes]:
    write = st.builds(
        lambda s, v, x, t, i: serialize_message(
            WriteVariable(slave=s, variable=v, value=x, text=t, request_id=i)
        ),
        st.sampled_from(SLAVES),
        st.sampled_from(NAMES),
        st.floats(),
        st.sampled_from(["", "1"]),
        st.integers(0, 2**32 - 1),
    )
    return write.map(lambda b: (WriteVariable, b))  # type: ignore[no-any-return]


@FUZZ
@given(
    base=_serialized(),
    flips=st.lists(st.tuples(st.integers(0, 200), st.integers(0, 255)), max_size=6),
    cut=st.integers(0, 200),
    noise=st.binary(max_size=64),
    kind=st.sampled_from([WriteVariable, JointState, JointTrajectory]),
)
def test_any_bytes_are_read_or_refused_before_rclpy_cuts_them(
    base: tuple[Any, bytes], flips: list[tuple[int, int]], cut: int, noise: bytes, kind: Any
) -> None:
    _type, data = base
    mutated = bytearray(data)
    for at, byte in flips:
        if at < len(mutated):
            mutated[at] = byte
    for candidate in (bytes(mutated[: max(cut, 1)]), bytes(mutated), noise):
        message, problem = checked_message(candidate, kind)
        assert problem is not None or message is not None
        if problem is None and kind is WriteVariable:
            assert "\0" not in message.variable + message.slave + message.text


class FakeAxis:
    """An axis as the bridge sees it: a mode, limits, a status and the two checks."""

    def __init__(self, name: str, index: int) -> None:
        self.name, self.index, self.mode = name, index, "csp"
        config = SimpleNamespace(
            position_limits=(-2.0, 2.0),
            velocity_limit=3.0,
            torque_limit=1.0,
            max_acceleration=None,
            deceleration=math.inf,
        )
        self.spec = SimpleNamespace(modes=("csp", "csv"), config=config)

    def status(self) -> dict[str, Any]:
        return {"state": "operation_enabled", "position": 0.0, "velocity": 0.0,
                "target_position": 0.0}  # fmt: skip

    def check_command(self, kind: str, value: float) -> None:
        if not -2.0 <= value <= 2.0:
            raise EtherRosError(f"joint {self.name!r}: position {value} is outside the limits")

    def check_trajectory(self, track: list[tuple[float, float, float]]) -> None:
        for _t, p, v in track:
            if not (math.isfinite(p) and math.isfinite(v)) or abs(p) > 2.0:
                raise EtherRosError(f"joint {self.name!r}: outside the limits")


AXES = {n: FakeAxis(n, i) for i, n in enumerate(["hip", "knee", "elbow"])}
joint_names = st.lists(st.one_of(st.sampled_from(list(AXES)), st.text(max_size=12)), max_size=4)
values = st.lists(floats, max_size=4)


@FUZZ
@given(names=joint_names, position=values, velocity=values, effort=values)
def test_any_joint_command_is_resolved_or_refused(
    names: list[str], position: list[float], velocity: list[float], effort: list[float]
) -> None:
    try:
        commands = bridge.resolve_joint_command(AXES, names, position, velocity, effort)
    except MessageError as exc:
        assert exc.field in ("name", "position", "velocity", "effort"), exc
        return
    assert [a.name for a, _k, _v in commands] == names
    assert all(-2.0 <= v <= 2.0 for _a, _k, v in commands)


@FUZZ
@given(
    names=joint_names,
    points=st.lists(
        st.tuples(st.integers(-5, 10**10), st.integers(0, 10**9 - 1), values, values), max_size=5
    ),
)
def test_any_trajectory_is_planned_or_refused(
    names: list[str], points: list[tuple[int, int, list[float], list[float]]]
) -> None:
    msg = JointTrajectory(joint_names=names)
    for sec, nanosec, positions, velocities in points:
        p = JointTrajectoryPoint(positions=positions, velocities=velocities)
        p.time_from_start.sec, p.time_from_start.nanosec = (
            max(min(sec, 2**31 - 1), -(2**31)),
            nanosec,
        )
        msg.points.append(p)
    now = 1_000_000_000_000
    try:
        plan = joints.trajectory_plan(AXES, msg, capacity=64, wall_now_ns=now, engine_now_ns=now)
    except MessageError:
        return
    assert plan.names == names
    assert plan.start_ns == now and plan.end_ns >= now
