"""The console's CiA 402 commands (enable, disable, reset_fault, set_mode, move): parsed and
checked against the joints' modes and limits before anything is sent."""

from __future__ import annotations

import math

import pytest

from ether_ros.console.commands import (
    AxisOp,
    CommandError,
    ConsoleContext,
    JointLimits,
    Move,
    SetMode,
    parse_command,
)

CTX = ConsoleContext(
    None,
    joints={
        "elbow": JointLimits("csp", (-2.5, 2.5), 3.0, 8.0),
        "wrist": JointLimits("csv", (-3.1, 3.1), 4.0, 4.0),
        "grip": JointLimits("cst", (-1.0, 1.0), 1.0, 2.0),
        "lift": JointLimits("hm", (-1.0, 1.0), 1.0, 2.0),
    },
)


@pytest.mark.parametrize(
    ("line", "command"),
    [
        ("enable", AxisOp("enable")),
        ("enable all", AxisOp("enable")),
        ("disable elbow wrist", AxisOp("disable", ("elbow", "wrist"))),
        ("reset_fault grip", AxisOp("reset_fault", ("grip",))),
        ("set_mode elbow CSV", SetMode("csv", ("elbow",))),
        ("set_mode all csp", SetMode("csp")),
        ("move elbow -2.5", Move("elbow", "position", -2.5)),
        ("move wrist 4", Move("wrist", "velocity", 4.0)),
        ("move grip -2", Move("grip", "effort", -2.0)),
    ],
)
def test_valid_axis_commands(line: str, command: object) -> None:
    assert parse_command(line, CTX) == command


@pytest.mark.parametrize(
    ("line", "why"),
    [
        ("enable nope", "unknown joint 'nope' (joints: elbow, wrist, grip, lift)"),
        ("disable elbow elbow", "named twice"),
        ("set_mode elbow warp", "unknown mode 'warp' (modes: pp, pv, hm, csp, csv, cst)"),
        ("set_mode elbow", "usage: set_mode JOINT|all MODE"),
        ("move elbow 2.6", "position 2.6 is outside the limits [-2.5, 2.5]"),
        ("move wrist -4.5", "velocity -4.5 is beyond the limit ±4"),
        ("move grip 3", "torque 3 is beyond the limit ±2"),
        ("move elbow nan", "not a finite number"),
        ("move elbow x", "'x' is not a number"),
        ("move lift 0", "mode hm: it takes no setpoint"),
        ("move all 0", "move takes one joint"),
        ("move elbow", "usage: move JOINT VALUE"),
    ],
)
def test_bad_axis_commands_are_refused_before_sending(line: str, why: str) -> None:
    with pytest.raises(CommandError) as exc:
        parse_command(line, CTX)
    assert why in str(exc.value)


def test_a_bus_without_axes_says_so() -> None:
    with pytest.raises(CommandError, match="no CiA 402 axes known"):
        parse_command("enable", ConsoleContext(None))


def test_limits_may_be_unbounded() -> None:
    ctx = ConsoleContext(None, joints={"j": JointLimits("csp", (-math.inf, math.inf), 1, 1)})
    assert parse_command("move j 1e6", ctx) == Move("j", "position", 1e6)


def test_joint_names_and_modes_complete() -> None:
    from ether_ros.console.completion import complete

    assert complete("enable e", CTX) == ["elbow"]
    assert complete("set_mode a", CTX) == ["all"]
    assert complete("set_mode elbow cs", CTX) == ["csp", "csv", "cst"]
    assert complete("move w", CTX) == ["wrist"]
