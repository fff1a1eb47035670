"""Tab completion: commands, then slave names, then variable names from the published layout."""

from __future__ import annotations

import pytest

from bus_specs import spec_of
from ether_ros.console.commands import ConsoleContext
from ether_ros.console.completion import complete


@pytest.fixture(scope="module")
def ctx() -> ConsoleContext:
    return ConsoleContext(spec_of("laelaps.yaml"))


def test_commands_slaves_and_variables(ctx: ConsoleContext) -> None:
    assert complete("pa", ctx) == ["panic"]
    assert "restart" in complete("", ctx)
    assert complete("set fr", ctx) == ["front_left_leg", "front_right_leg"]
    assert complete("set a", ctx) == ["all"]
    assert complete("set front_left_leg b_", ctx) == ["b_ellipse100="]
    assert complete("set all Kp", ctx) == ["Kp100_knee=", "Kp100_hip="]
    assert complete("set front_left_leg hip", ctx) == []  # inputs cannot be set
    assert complete("get front_left_leg hip", ctx) == ["hip_angle"]
    assert complete("sdo r", ctx) == ["read"]
    assert complete("sdo read front_left_leg 0x1018:01 ui", ctx)[0] == "uint8"
    assert complete("help se", ctx) == ["set", "set_mode"]


def test_unknown_slave_or_no_layout_completes_nothing(ctx: ConsoleContext) -> None:
    assert complete("set nobody K", ctx) == []
    assert complete("set fr", ConsoleContext(None)) == []
    assert complete("set 'unclosed", ctx) == []
