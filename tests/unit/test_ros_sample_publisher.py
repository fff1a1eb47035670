"""The sample publisher: decimation, decoding, joint states in SI, flag counting, and dropping
(and counting) samples when ROS falls behind. The bus is faked (one layer): its layout comes
from the real configuration and image plan, its samples are built here."""

from __future__ import annotations

import struct
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest

import engine_plans
from ether_ros.config import load_bus_config
from ether_ros.master.plan import layout_image
from ether_ros.master.samples import FLAG_LOST, FLAG_WATCHDOG, SAMPLE_DTYPE, Samples
from ether_ros.ros import bridge
from ether_ros.ros.layout import BusSpec
from ether_ros.ros.sample_publisher import Rates, SamplePublisher

REPO = Path(__file__).resolve().parents[2]


@dataclass
class FakeSlave:
    name: str
    position: int
    layout: Any
    area: Any


class FakeBus:
    def __init__(self, cfg: Any) -> None:
        self.config = cfg
        self.layout = layout_image(
            [(i, 0x1000 + i, s.name, s.layout.output_bytes, s.layout.input_bytes)
             for i, s in enumerate(cfg.slaves)]
        )  # fmt: skip
        self.slaves = [
            FakeSlave(s.name, i, s.layout, a)
            for i, (s, a) in enumerate(zip(cfg.slaves, self.layout.slaves, strict=True))
        ]


class Sink:
    def __init__(self) -> None:
        self.messages: list[Any] = []

    def publish(self, msg: Any) -> None:
        self.messages.append(msg)


@pytest.fixture
def rig() -> tuple[FakeBus, dict[str, Sink], SamplePublisher]:
    cfg = load_bus_config(REPO / "config" / "laelaps.yaml")
    bus = FakeBus(cfg)
    spec = BusSpec(
        "laelaps_ii",
        400,
        tuple(bridge.slave_spec(s.name, s.position, "LaelapsII_Leg", s.layout) for s in bus.slaves),
    )
    sinks = {t: Sink() for t in ("pdo_raw", "pdo_in", "pdo_out", "joint_states")}
    pub = SamplePublisher(
        bus, spec, sinks, cfg.joint_specs(), Rates(2, 10), lambda: True, max_backlog=100
    )
    return bus, sinks, pub


def batch(bus: FakeBus, cycles: range, flags: int = 0, hip_angle: int = 0) -> Samples:
    n = len(cycles)
    records = np.zeros(n, dtype=SAMPLE_DTYPE)
    records["cycle"] = list(cycles)
    records["wkc"] = 12
    records["flags"] = flags
    records["dc_diff_ns"] = -250
    images = np.zeros((n, bus.layout.image_len), dtype=np.uint8)
    leg = bus.slaves[2]  # front_left_leg
    offset = leg.area.input_offset + leg.layout.variable("hip_angle").byte_offset
    images[:, offset : offset + 2] = np.frombuffer(struct.pack("<h", hip_angle), np.uint8)
    out = leg.area.output_offset + leg.layout.variable("Kp100_knee").byte_offset
    images[:, out : out + 2] = np.frombuffer(struct.pack("<h", 8000), np.uint8)
    return Samples(records, images)


def test_decimation_decoding_and_joint_states(rig: Any) -> None:
    bus, sinks, pub = rig
    assert pub._publish_batch(batch(bus, range(0, 50), hip_angle=9000)) == 50
    assert [m.cycle for m in sinks["pdo_raw"].messages] == list(range(0, 50, 2))
    raw = sinks["pdo_raw"].messages[0]
    assert len(raw.pdo_out) == bus.layout.output_bytes
    assert len(raw.pdo_in) == bus.layout.input_bytes
    assert raw.working_counter == raw.expected_working_counter == 12
    # Every 10th cycle: one pdo_in and one pdo_out message per slave, one joint_states.
    assert len(sinks["pdo_in"].messages) == len(sinks["pdo_out"].messages) == 5 * 4
    fl_in = next(m for m in sinks["pdo_in"].messages if m.slave == "front_left_leg")
    assert fl_in.values[0] == 9000.0 and fl_in.position == 2 and fl_in.cycle == 0
    fl_out = next(m for m in sinks["pdo_out"].messages if m.slave == "front_left_leg")
    names = [v.name for v in bus.slaves[2].layout.outputs]
    assert fl_out.values[names.index("Kp100_knee")] == 8000.0
    js = sinks["joint_states"].messages[-1]
    assert js.name[4] == "fl_hip"
    assert js.position[4] == pytest.approx(9000 * 0.000174533)  # 90.00° in rad
    assert js.position[0] == 0.0
    assert pub.counters.dc_error_max_ns == 250 and pub.take_dc_error() == 250
    assert pub.counters.dc_error_max_ns == 0


def test_samples_beyond_the_backlog_are_dropped_and_counted(rig: Any) -> None:
    bus, sinks, pub = rig
    pub.rates.raw_decimation = 1
    assert pub._publish_batch(batch(bus, range(1000, 1250))) == 250
    assert pub.counters.dropped == 150
    assert pub.counters.samples == 250
    # The newest samples are the ones published.
    assert [m.cycle for m in sinks["pdo_raw"].messages] == list(range(1150, 1250))


def test_flags_are_counted(rig: Any) -> None:
    bus, _sinks, pub = rig
    pub._publish_batch(batch(bus, range(0, 30), flags=FLAG_LOST))
    pub._publish_batch(batch(bus, range(30, 40), flags=FLAG_WATCHDOG))
    c = pub.counters
    assert (c.lost, c.watchdog_cycles, c.last_cycle, c.last_flags) == (30, 10, 39, FLAG_WATCHDOG)
    assert pub._publish_batch(batch(bus, range(0))) == 0


def test_axis_joints_carry_the_values_of_their_own_sample(rig: Any) -> None:
    """A backlog published in one go (the publisher after a stall): each joint_states message
    has the axis values of the cycle its stamp names, converted as the engine converts them,
    not the axis's state at publishing time."""
    from ether_ros.ros.joints import AxisImageJoints

    bus, sinks, pub = rig
    at = bus.layout.image_len - 12  # 10 spare bytes at the image's end for a made-up axis
    scales = {"position_scale": 1e-4, "position_offset": 0.5, "velocity_scale": 1e-3,
              "torque_scale": 0.01}  # fmt: skip
    # controlword and statusword are required; this test reads only the actual values.
    objects = {"controlword": 0, "statusword": 0}
    entry = engine_plans.axis_plan(
        "elbow", {**objects, "position": at, "velocity": at + 4, "torque": at + 8}, **scales
    )
    pub._axis_joints = AxisImageJoints([entry])
    samples = batch(bus, range(0, 50))
    for row, cycle in enumerate(samples.records["cycle"]):
        samples.images[row, at : at + 10] = np.frombuffer(
            struct.pack("<iih", 100 * int(cycle), -7 * int(cycle), 3 * int(cycle)), np.uint8
        )
    assert pub._publish_batch(samples) == 50
    messages = sinks["joint_states"].messages
    assert len(messages) == 5
    for msg, cycle in zip(messages, range(0, 50, 10), strict=True):
        k = msg.name.index("elbow")
        assert msg.position[k] == pytest.approx(100 * cycle * 1e-4 + 0.5)
        assert msg.velocity[k] == pytest.approx(-7 * cycle * 1e-3)
        assert msg.effort[k] == pytest.approx(3 * cycle * 0.01)
    # An object the PDOs do not map reads raw 0 (position: the offset), as in the engine.
    unmapped = engine_plans.axis_plan("elbow", objects, **scales)
    assert AxisImageJoints([unmapped])(bytes(16)) == [("elbow", 0.5, 0.0, 0.0)]
