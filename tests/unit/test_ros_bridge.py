"""The ROS side's view of the bus, without ROS: layout specs, the fast area decoder, write
resolution and checking, statistics, and the configuration as parameters."""

from __future__ import annotations

import random
from pathlib import Path

import pytest

from bus_specs import spec_of
from ether_ros.config import load_bus_config
from ether_ros.ros import bridge
from ether_ros.ros.layout import parse_address

REPO = Path(__file__).resolve().parents[2]


def load(name: str):  # type: ignore[no-untyped-def]
    return load_bus_config(REPO / "config" / name)


@pytest.mark.parametrize("config", ["laelaps.yaml", "generic_io.yaml", "mixed.yaml"])
def test_area_decoder_matches_the_layout_codec(config: str) -> None:
    rng = random.Random(7)
    for s in load(config).slaves:
        layout = s.layout
        for variables, size, direction in (
            (layout.inputs, layout.input_bytes, "input"),
            (layout.outputs, layout.output_bytes, "output"),
        ):
            decoder = bridge.area_decoder(variables)
            for _ in range(20):
                area = bytes(rng.randrange(256) for _ in range(size))
                expected = [float(v) for v in layout.unpack(area, direction).values()]
                assert decoder.decode(area) == expected


def test_spec_names_types_and_ranges() -> None:
    leg = spec_of("laelaps.yaml").slave("front_left_leg")
    assert leg.position == 2 and leg.device == "LaelapsII_Leg"
    b = leg.output("b_ellipse100")
    assert (b.type, b.index, b.subindex, b.minimum, b.maximum) == (
        "int16",
        0x7030,
        4,
        -32768.0,
        32767.0,
    )
    assert leg.output("0x7030:04") == b == leg.output("7030:4") == leg.output("B_ELLIPSE100")
    assert leg.input("hip_angle").type == "int16"
    assert leg.output("State_Machine").type == "bool"
    assert parse_address("0x7030:04") == (0x7030, 4) and parse_address("x:y") is None


def test_bus_layout_carries_each_slaves_group_and_its_cycle() -> None:
    from types import SimpleNamespace

    from ether_ros.master.plan import ImageSlave, layout_image
    from ether_ros.ros.convert import layout_msg, spec_from_msg

    cfg = load_bus_config(Path(__file__).resolve().parents[2] / "config" / "mixed.yaml")
    slaves = [
        SimpleNamespace(name=s.name, position=i, device=s.esi, layout=s.layout)
        for i, s in enumerate(cfg.slaves)
    ]
    image = layout_image(
        [ImageSlave(i, 0x1001 + i, s.name, 1, 1, "io" if s.name == "io_box" else "default")
         for i, s in enumerate(cfg.slaves)],
        groups=[("default", 1), ("io", 5)],
    )  # fmt: skip
    bus = SimpleNamespace(config=cfg, slaves=slaves, layout=image)
    spec = spec_from_msg(layout_msg(bridge.bus_spec(bus)))
    assert (spec.slave("io_box").group, spec.slave("io_box").group_cycle_us) == ("io", 2000)
    leg = spec.slave("hind_right_leg")
    assert (leg.group, leg.group_cycle_us) == ("default", 400)


def test_resolve_write_by_name_position_all_and_text() -> None:
    s = spec_of("laelaps.yaml")
    [(slave, var, value)] = bridge.resolve_write(s, "", 3, False, "Kp100_knee", 8000.0, "")
    assert (slave.name, var.name, value) == ("front_right_leg", "Kp100_knee", 8000.0)
    writes = bridge.resolve_write(s, "", -1, True, "0x7030:04", 0.0, "0x4")
    assert [(w[0].name, w[2]) for w in writes] == [(x.name, 4.0) for x in s.slaves]
    [(_, var, value)] = bridge.resolve_write(s, "hind_left_leg", -1, False, "Blue_LED", 0, "on")
    assert (var.name, value) == ("Blue_LED", 1.0)


@pytest.mark.parametrize(
    ("args", "reason", "field"),
    [
        (("", -1, False, "Kp100_knee", 1.0, ""), "no slave given", "slave"),
        (("x", -1, False, "Kp100_knee", 1.0, ""), "no slave named 'x'", "slave"),
        (("", 9, False, "Kp100_knee", 1.0, ""), "no slave at position 9", "position"),
        (("", -1, True, "hip_angle", 1.0, ""), "no slave has an output variable", "variable"),
        (("front_left_leg", -1, False, "hip_angle", 1.0, ""), "is an input", "variable"),
        (("front_left_leg", -1, False, "", 1.0, ""), "no variable given", "variable"),
        (("front_left_leg", -1, False, "Kp100_knee", 1e9, ""), "outside -32768..32767", "value"),
        (
            ("front_left_leg", -1, False, "Kp100_knee", float("nan"), ""),
            "not a finite number",
            "value",
        ),
        (("front_left_leg", -1, False, "Kp100_knee", 0.0, "1e3x"), "not an integer", "text"),
        (("front_left_leg", -1, False, "State_Machine", 0.5, ""), "not an integer", "value"),
        # one slave or all of them, never both (issue 19: both wrote every slave)
        (
            ("front_left_leg", -1, True, "Kp100_knee", 1.0, ""),
            "all_slaves is true and slave",
            "all_slaves",
        ),
        (("", 2, True, "Kp100_knee", 1.0, ""), "all_slaves is true and position 2", "all_slaves"),
        # names and text: control characters and overlong strings, before any lookup
        (
            ("front_left_leg", -1, False, "Kp100_knee\x1b[2J", 1.0, ""),
            "variable: character 10",
            "variable",
        ),
        (("front\nleft", -1, False, "Kp100_knee", 1.0, ""), "slave: character 5", "slave"),
        (("front_left_leg", -1, False, "x" * 300, 1.0, ""), "variable: 300 characters", "variable"),
        (("front_left_leg", -1, False, "Kp100_knee", 0.0, "1\x00"), "text: character 1", "text"),
    ],
)
def test_resolve_write_refuses_with_the_reason(args: tuple, reason: str, field: str) -> None:  # type: ignore[type-arg]
    with pytest.raises(bridge.WriteRejected) as err:
        bridge.resolve_write(spec_of("laelaps.yaml"), *args)
    assert reason in str(err.value)
    assert err.value.field == field, "the refusal names the message field as data"


def test_flat_stats_and_lookup() -> None:
    stats = {"counters": {"lost_frames": 3, "cycles": 10}, "rtt": {"p99": 50}, "ok": True}
    flat = bridge.flat_stats(stats)
    assert flat == {"counters.lost_frames": 3.0, "counters.cycles": 10.0, "rtt.p99": 50.0,
                    "ok": 1.0}  # fmt: skip
    assert bridge.stat(flat, "lost_frames") == 3.0
    assert bridge.stat(flat, "rtt.p99") == 50.0
    assert bridge.stat(flat, "missing") == 0.0


def test_configuration_as_parameters() -> None:
    from ether_ros.ros.node import config_parameters

    params = config_parameters(load("laelaps.yaml"))
    assert params["bus.cycle_us"] == 400
    assert params["bus.dc.mode"] == "ref_follows_master"
    assert params["bus.realtime.cpu"] == 1
    assert params["ros.node_name"] == "ether_comm"
    assert params["slaves.hind_right_leg.position"] == 0
    assert params["slaves.hind_right_leg.product_code"] == 0x00A986FD
    assert params["slaves.hind_right_leg.safe_outputs.State_Machine"] == 0
    assert params["slaves.front_left_leg.joints"] == ["fl_hip", "fl_knee"]
    assert params["esi"] == ["../devices"]
    assert all(v is not None and not isinstance(v, dict) for v in params.values())
