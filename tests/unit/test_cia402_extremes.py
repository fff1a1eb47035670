"""Float extremes in a CiA 402 axis (issue 30 item 5): every one is taken or refused with an
error naming the key — never an OverflowError from a conversion to the drive's counts."""

from __future__ import annotations

import copy
from pathlib import Path
from typing import Any

import pytest
import yaml

from ether_ros.config import load_bus_config
from ether_ros.config.cia402 import software_limits_raw
from ether_ros.errors import ConfigError

REPO = Path(__file__).resolve().parents[2]


def _arm_with(tmp_path: Path, key: str, value: Any) -> Path:
    data = yaml.safe_load((REPO / "config" / "arm6.yaml").read_text())
    data["esi"] = [str(REPO / "devices" / "servo_drive.xml")]
    data = copy.deepcopy(data)
    data["slaves"][0]["axes"][0][key] = value
    path = tmp_path / "arm.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


@pytest.mark.parametrize(
    ("key", "value", "why"),
    [
        ("position_scale", 1e-308, r"position_scale: must be within 1e-15\.\.1000"),
        ("position_scale", 1e308, r"position_scale: must be within"),
        ("velocity_scale", 1e-308, r"velocity_scale: must be within"),
        ("torque_scale", 1e308, r"torque_scale: must be within"),
        ("profile_velocity", 1e308, r"profile_velocity: profile_velocity 1e\+308 is .* outside"),
        ("profile_velocity", 1e-308, r"profile_velocity: profile_velocity 1e-308 is 0 in"),
    ],
)
def test_extremes_are_refused_naming_the_key(
    tmp_path: Path, key: str, value: float, why: str
) -> None:
    with pytest.raises(ConfigError, match=why):
        load_bus_config(_arm_with(tmp_path, key, value))


@pytest.mark.parametrize(
    ("key", "value"),
    [("position_limits", [-1e308, 1e308]), ("torque_limit", 1e308), ("velocity_limit", 1e308)],
)
def test_limits_beyond_the_drive_range_are_taken(tmp_path: Path, key: str, value: Any) -> None:
    cfg = load_bus_config(_arm_with(tmp_path, key, value))
    axis = cfg.slaves[0].axes[0]
    if key == "position_limits":
        # Beyond what the drive's INT32 counts hold: the drive's own ends of range.
        assert software_limits_raw(axis) == (-(2**31), 2**31 - 1)
