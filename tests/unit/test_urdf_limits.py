"""Limits and joint names from the robot's URDF (``urdf:`` in the bus configuration,
config/urdf.py): what the URDF gives, what the bus configuration overrides, and the refusals."""

from __future__ import annotations

import math
import re
from pathlib import Path

import pytest

from ether_ros.config.bus import BusConfig, load_bus_config
from ether_ros.errors import ConfigError

REPO = Path(__file__).resolve().parents[2]
ARM6 = REPO / "config" / "arm6.yaml"
ARM6_URDF = REPO / "config" / "arm6.urdf"
ESI = REPO / "devices" / "servo_drive.xml"
LIMIT_KEYS = ("position_limits", "velocity_limit", "torque_limit")


def _axes(cfg: BusConfig) -> dict[str, tuple[tuple[float, float], float, float]]:
    return {
        a.name: (a.position_limits, a.velocity_limit, a.torque_limit)
        for s in cfg.slaves
        for a in s.axes
    }


def _bus(tmp_path: Path, urdf: str, axes: str) -> Path:
    """A one-drive bus (two axes) whose config names ``robot.urdf`` holding ``urdf``."""
    (tmp_path / "robot.urdf").write_text(urdf)
    cfg = tmp_path / "bus.yaml"
    cfg.write_text(
        f"bus: {{name: t, cycle_us: 1000}}\nesi: [{ESI}]\nurdf: robot.urdf\n"
        f"slaves:\n  - name: d\n    device: ServoDrive2\n    axes:\n{axes}"
    )
    return cfg


TWO_AXES = "      - {name: a}\n      - {name: b}\n"


def _robot(*joints: str) -> str:
    return '<?xml version="1.0"?>\n<robot name="r">\n' + "\n".join(joints) + "\n</robot>\n"


def _joint(name: str, kind: str = "revolute", limit: str = "") -> str:
    lim = f"<limit {limit}/>" if limit else ""
    return (
        f'<joint name="{name}" type="{kind}"><parent link="p"/><child link="c_{name}"/>'
        f"{lim}</joint>"
    )


def test_arm6_with_its_urdf_has_the_same_limits(tmp_path: Path) -> None:
    # arm6.yaml without its limit keys, reading them from config/arm6.urdf instead.
    text = ARM6.read_text()
    stripped = re.sub(r"position_limits: \[[^\]]*\],\s*", "", text)
    stripped = re.sub(r"(velocity|torque)_limit: [0-9.]+,\s*", "", stripped)
    assert "position_limits:" not in stripped and "_limit:" not in stripped
    stripped = stripped.replace("esi: [../devices/servo_drive.xml]", f"esi: [{ESI}]")
    stripped = stripped.replace("# urdf: arm6.urdf", f"urdf: {ARM6_URDF}")
    assert f"urdf: {ARM6_URDF}" in stripped
    (tmp_path / "arm6_urdf.yaml").write_text(stripped)
    with_urdf = load_bus_config(tmp_path / "arm6_urdf.yaml")
    original = _axes(load_bus_config(ARM6))
    assert _axes(with_urdf) == original
    # ... and the axes' resolved specs (what the engine gets) agree too.
    assert [s.config.position_limits for sl in with_urdf.slaves for s in sl.axis_specs] == [
        v[0] for v in original.values()
    ]


def test_urdf_fills_what_the_axis_leaves_out_and_the_bus_config_wins(tmp_path: Path) -> None:
    urdf = _robot(
        _joint("a", limit='lower="-1.5" upper="2" velocity="3" effort="7"'),
        _joint("b", "continuous", limit='lower="-1" upper="1" velocity="5" effort="2"'),
        _joint("elsewhere", limit='lower="0" upper="1" velocity="1" effort="1"'),
        _joint("mount", "fixed"),
    )
    axes = "      - {name: a, velocity_limit: 1.0}\n      - {name: b}\n"
    got = _axes(load_bus_config(_bus(tmp_path, urdf, axes)))
    assert got["a"] == ((-1.5, 2.0), 1.0, 7.0)  # velocity_limit set in the bus config wins
    lo, hi = got["b"][0]  # continuous: no position limits, whatever <limit> says
    assert (lo, hi) == (-math.inf, math.inf) and got["b"][1:] == (5.0, 2.0)


def test_position_limits_set_in_the_bus_config_win(tmp_path: Path) -> None:
    urdf = _robot(
        _joint("a", limit='lower="-1.5" upper="2" velocity="3" effort="7"'),
        _joint("b", limit='lower="-1" upper="1"'),
    )
    axes = "      - {name: a, position_limits: [-0.5, 0.5]}\n      - {name: b}\n"
    got = _axes(load_bus_config(_bus(tmp_path, urdf, axes)))
    assert got["a"] == ((-0.5, 0.5), 3.0, 7.0)
    assert got["b"] == ((-1.0, 1.0), math.inf, math.inf)  # only the attributes given


def test_without_urdf_key_nothing_changes(tmp_path: Path) -> None:
    cfg = _bus(tmp_path, _robot(_joint("a", limit='lower="-1" upper="1" velocity="1" effort="1"')),
               TWO_AXES)  # fmt: skip
    cfg.write_text(cfg.read_text().replace("urdf: robot.urdf\n", ""))
    got = _axes(load_bus_config(cfg))
    assert got["a"] == ((-math.inf, math.inf), math.inf, math.inf)


@pytest.mark.parametrize(
    ("joints", "field", "words"),
    [
        ([_joint("a", limit='lower="nan" upper="1"')], "joint[a].limit.lower", "finite"),
        ([_joint("a", limit='lower="0" upper="x1"')], "joint[a].limit.upper", "not a number"),
        ([_joint("a", limit='lower="2" upper="1"')], "joint[a].limit", "lower must be <= upper"),
        ([_joint("a", limit='velocity="0"')], "joint[a].limit.velocity", "positive"),
        ([_joint("a", limit='effort="-3"')], "joint[a].limit.effort", "positive"),
        ([_joint("a", limit='velocity="inf"')], "joint[a].limit.velocity", "finite"),
        ([_joint("a"), _joint("a")], "joint[a].name", "duplicate"),
        ([_joint("a", "hinge")], "joint[a].type", "unknown joint type"),
        ([_joint("a", "fixed")], "joint[a].type", "must be one of"),
    ],
)
def test_bad_urdf_joint_is_refused_naming_file_and_field(
    tmp_path: Path, joints: list[str], field: str, words: str
) -> None:
    with pytest.raises(ConfigError) as info:
        load_bus_config(_bus(tmp_path, _robot(*joints), TWO_AXES))
    err = info.value
    assert err.field == field and err.file == str(tmp_path / "robot.urdf")
    assert str(tmp_path / "robot.urdf") in str(err) and field in str(err) and words in str(err)


def test_urdf_naming_no_axis_is_refused(tmp_path: Path) -> None:
    urdf = _robot(_joint("x", limit='lower="-1" upper="1" velocity="1" effort="1"'))
    with pytest.raises(ConfigError) as info:
        load_bus_config(_bus(tmp_path, urdf, TWO_AXES))
    assert info.value.field == "urdf" and "no axis is named like a movable joint" in str(info.value)
    assert "its joints: x" in str(info.value) and "the axes: a, b" in str(info.value)


def test_missing_urdf_is_refused_naming_the_key(tmp_path: Path) -> None:
    cfg = _bus(tmp_path, _robot(), TWO_AXES)
    (tmp_path / "robot.urdf").unlink()
    with pytest.raises(ConfigError) as info:
        load_bus_config(cfg)
    assert info.value.field == "urdf" and "URDF file not found" in str(info.value)
    assert str(cfg) in str(info.value)


@pytest.mark.parametrize(
    ("text", "words"),
    [
        ('<?xml version="1.0"?><!DOCTYPE r [<!ENTITY a "aaaa">]><robot name="&a;"/>', "DOCTYPE"),
        ("<robot><joint name='a'", "not well-formed XML"),
        ("<sdf/>", "root element is <robot>"),
    ],
)
def test_hostile_or_broken_urdf_is_refused(tmp_path: Path, text: str, words: str) -> None:
    with pytest.raises(ConfigError) as info:
        load_bus_config(_bus(tmp_path, text, TWO_AXES))
    assert words in str(info.value) and str(tmp_path / "robot.urdf") in str(info.value)


def test_urdf_that_is_not_a_regular_file_is_refused(tmp_path: Path) -> None:
    import os

    cfg = _bus(tmp_path, _robot(), TWO_AXES)
    (tmp_path / "robot.urdf").unlink()
    os.mkfifo(tmp_path / "robot.urdf")  # reading a FIFO would wait forever
    with pytest.raises(ConfigError) as info:
        load_bus_config(cfg)
    assert "not a regular file" in str(info.value)


def test_the_acceleration_limit_comes_from_the_config_the_urdf_or_the_deceleration(
    tmp_path: Path,
) -> None:
    from ether_ros.config.cia402 import acceleration_limit

    # issue 24: <limit acceleration=…> (joint_limits.yaml's max_acceleration) fills
    # max_acceleration where the axis leaves it out; the axis's own key wins.
    urdf = _robot(
        _joint("a", limit='lower="-1" upper="1" velocity="2" effort="3" acceleration="7.5"'),
        _joint("b", limit='lower="-1" upper="1" velocity="2" effort="3" acceleration="7.5"'),
    )
    axes = "      - {name: a}\n      - {name: b, max_acceleration: 12.0}\n"
    cfg = load_bus_config(_bus(tmp_path, urdf, axes))
    a, b = cfg.slaves[0].axes
    assert (acceleration_limit(a), acceleration_limit(b)) == (7.5, 12.0)
    # Neither given: the deceleration, else no limit beyond the velocity limit.
    urdf = _robot(_joint("a"), _joint("b"))
    axes = "      - {name: a, deceleration: 20.0}\n      - {name: b}\n"
    a, b = load_bus_config(_bus(tmp_path, urdf, axes)).slaves[0].axes
    assert (acceleration_limit(a), acceleration_limit(b)) == (20.0, math.inf)
    # Refused, naming the key.
    for bad in ("0.0", "-1.0", ".nan"):
        axes = f"      - {{name: a, max_acceleration: {bad}}}\n      - {{name: b}}\n"
        with pytest.raises(ConfigError, match="max_acceleration"):
            load_bus_config(_bus(tmp_path, urdf, axes))
    urdf = _robot(_joint("a", limit='velocity="2" effort="3" acceleration="-4"'), _joint("b"))
    with pytest.raises(ConfigError, match=r"limit\.acceleration"):
        load_bus_config(_bus(tmp_path, urdf, TWO_AXES))
