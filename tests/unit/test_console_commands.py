"""The console's command parser: a pure function from a line (and what is known about the bus)
to a checked command. Every invalid command raises CommandError with a reason; nothing else."""

from __future__ import annotations

import pytest

from bus_specs import spec_of
from ether_ros.console.commands import (
    CommandError,
    ConsoleContext,
    Control,
    Get,
    Help,
    Quit,
    RunSequence,
    SdoRead,
    SdoWrite,
    Show,
    Wait,
    Write,
    WriteOp,
    parse_command,
)
from ether_ros.ros.layout import BusSpec

# Table 6.1 standing pose: centre (0, 599) mm, a = b = 0, 1 Hz, flat.
STANDING = {
    "x_cntr_traj1000": 0.0,
    "y_cntr_traj1000": 599.0,
    "a_ellipse100": 0.0,
    "b_ellipse100": 0.0,
    "traj_freq100": 100.0,
    "phase_deg": 0.0,
    "FlatnessParam100": 0.0,
}


@pytest.fixture(scope="module")
def laelaps() -> BusSpec:
    return spec_of("laelaps.yaml")


@pytest.fixture
def ctx(laelaps: BusSpec) -> ConsoleContext:
    return ConsoleContext(laelaps, {s.name: dict(STANDING) for s in laelaps.slaves})


def test_control_commands(ctx: ConsoleContext) -> None:
    assert parse_command("start", ctx) == Control("start")
    assert parse_command("  STOP ", ctx) == Control("stop")
    assert parse_command("restart", ctx) == Control("restart")
    assert parse_command("panic", ctx) == Control("panic")
    assert parse_command("clear", ctx) == Control("clear_panic")
    assert parse_command("", ctx) is None
    assert parse_command("# a comment", ctx) is None


def test_set_one_slave_by_name_and_position(ctx: ConsoleContext) -> None:
    assert parse_command("set front_left_leg Kp100_knee 8000", ctx) == Write(
        (WriteOp("front_left_leg", "Kp100_knee", 8000.0),)
    )
    cmd = parse_command("set 2 Kp100_knee=8000 Kd1000_knee=50", ctx)
    assert cmd == Write(
        (
            WriteOp("front_left_leg", "Kp100_knee", 8000.0),
            WriteOp("front_left_leg", "Kd1000_knee", 50.0),
        )
    )


def test_set_by_object_address_and_in_other_notations(ctx: ConsoleContext) -> None:
    assert parse_command("set hind_left_leg 0x7020:01 0x10", ctx) == Write(
        (WriteOp("hind_left_leg", "Kp100_knee", 16.0),)
    )
    cmd = parse_command("set hind_left_leg State_Machine=true Blue_LED=off", ctx)
    assert cmd == Write(
        (
            WriteOp("hind_left_leg", "State_Machine", 1.0),
            WriteOp("hind_left_leg", "Blue_LED", 0.0),
        )
    )


def test_set_all_expands_to_every_slave_with_the_variable(ctx: ConsoleContext) -> None:
    cmd = parse_command("set all b_ellipse100=4", ctx)
    assert isinstance(cmd, Write)
    assert [op.slave for op in cmd.ops] == [s.name for s in ctx.layout.slaves]  # type: ignore[union-attr]
    assert {op.value for op in cmd.ops} == {4.0}


@pytest.mark.parametrize(
    ("line", "reason"),
    [
        ("set nobody Kp100_knee 1", "no slave named 'nobody'"),
        ("set 9 Kp100_knee 1", "no slave at position 9"),
        ("set front_left_leg nothing 1", "has no output variable 'nothing'"),
        ("set front_left_leg hip_angle 1", "is an input"),
        ("set front_left_leg Kp100_knee 40000", "outside -32768..32767"),
        ("set front_left_leg FilterBandwidth -1", "outside 0..65535"),
        ("set front_left_leg Kp100_knee 1.5", "not an integer"),
        ("set front_left_leg Kp100_knee many", "not an integer"),
        ("set front_left_leg State_Machine 2", "outside 0..1"),
        ("set front_left_leg Transition_time 200", "outside -128..127"),
        ("set front_left_leg Kp100_knee", "usage: set"),
        ("set front_left_leg Kp100_knee=1 Kp100_knee=2", "assigned twice"),
        ("set front_left_leg Kp100_knee= ", "is not VAR=VALUE"),
        ("set all nothing=1", "no slave has the output variable"),
        ("set front_left_leg 0x9999:01 1", "maps no output variable at 0x9999:01"),
        ("frobnicate", "unknown command 'frobnicate'"),
        ("start now", "takes no arguments"),
        ("wait -1", "non-negative"),
        ("wait soon", "not a number of seconds"),
        ("get", "usage: get"),
        ("run", "usage: run"),
        ("set front_left_leg 'Kp100_knee", "cannot split"),
        ("sdo read front_left_leg 8000 uint8", "not an object address"),
        ("sdo read front_left_leg 0x8000:01 banana", "unsupported data type"),
        ("sdo write front_left_leg 0x8000:01 uint8 300", "outside 0..255"),
        ("sdo erase front_left_leg", "usage: sdo"),
    ],
)
def test_invalid_commands_are_refused_with_the_reason(
    ctx: ConsoleContext, line: str, reason: str
) -> None:
    with pytest.raises(CommandError) as err:
        parse_command(line, ctx)
    assert reason in str(err.value)


def test_thesis_trot_parameters_are_accepted(ctx: ConsoleContext) -> None:
    # Table 6.1: b to 4 cm, then a to 5 cm, at centre y 599 (fore) / 598 (hind) mm.
    cmd = parse_command("set all b_ellipse100=4", ctx)
    assert isinstance(cmd, Write)
    ctx = ctx.after(cmd)
    cmd = parse_command("set all a_ellipse100=5", ctx)
    assert isinstance(cmd, Write)
    assert parse_command("set hind_right_leg y_cntr_traj1000=598", ctx.after(cmd))


@pytest.mark.parametrize(
    ("line", "reason"),
    [
        # centre 650 mm: the stretched leg only reaches 600 mm (eq. 4.4)
        ("set front_left_leg y_cntr_traj1000=650", "outside the leg workspace"),
        # a = 20 cm swings the toe to (200, 599): 631 mm from the hip
        ("set front_left_leg a_ellipse100=20", "outside the leg workspace"),
        # centre 450 mm and b = 4 cm lifts the toe to 410 mm: closer than 430.12 mm
        ("set front_left_leg y_cntr_traj1000=450 b_ellipse100=4", "outside the leg workspace"),
        ("set front_left_leg a_ellipse100=-1", "negative semi-axis"),
        ("set front_left_leg traj_freq100=2000", "frequency 20 Hz"),
        ("set front_left_leg FlatnessParam100=150", "flatness 1.5"),
        ("set all a_ellipse100=20", "makes an invalid ellipse"),
    ],
)
def test_invalid_ellipses_are_refused_with_the_reason(
    ctx: ConsoleContext, line: str, reason: str
) -> None:
    with pytest.raises(CommandError) as err:
        parse_command(line, ctx)
    assert reason in str(err.value)
    assert "invalid ellipse" in str(err.value)


def test_workspace_check_needs_the_current_trajectory(laelaps: BusSpec) -> None:
    with pytest.raises(CommandError, match="current value of"):
        parse_command("set front_left_leg b_ellipse100=4", ConsoleContext(laelaps, {}))
    # Variables outside the trajectory record need no knowledge of the current values.
    assert parse_command("set front_left_leg Kp100_knee=8000", ConsoleContext(laelaps, {}))


def test_generic_io_slaves_get_no_workspace_check() -> None:
    spec = spec_of("generic_io.yaml")
    out = spec.slaves[0].outputs[0]
    ctx = ConsoleContext(spec, {})
    cmd = parse_command(f"set io_a {out.name} 1", ctx)
    assert isinstance(cmd, Write)


def test_other_commands(ctx: ConsoleContext) -> None:
    assert parse_command("get front_left_leg", ctx) == Get("front_left_leg")
    assert parse_command("get 0 hip_angle", ctx) == Get("hind_right_leg", "hip_angle")
    assert parse_command("states", ctx) == Show("states")
    assert parse_command("stats", ctx) == Show("stats")
    assert parse_command("layout 1", ctx) == Show("layout", "hind_left_leg")
    assert parse_command("sdo read front_left_leg 0x8000:01 uint8", ctx) == SdoRead(
        "front_left_leg", 0x8000, 1, "UINT8"
    )
    assert parse_command("sdo write 2 8000:1 uint8 3", ctx) == SdoWrite(
        "front_left_leg", 0x8000, 1, "UINT8", "3"
    )
    assert parse_command("run 'my trot.yaml' step", ctx) == RunSequence("my trot.yaml", True)
    assert parse_command("wait 1.5", ctx) == Wait(1.5)
    assert parse_command("help set", ctx) == Help("set")
    assert parse_command("exit", ctx) == Quit()


def test_without_a_layout_writes_are_refused_but_control_works() -> None:
    ctx = ConsoleContext(None)
    assert parse_command("start", ctx) == Control("start")
    with pytest.raises(CommandError, match="layout is not known"):
        parse_command("set all b_ellipse100=4", ctx)


def test_a_fresh_leg_is_told_to_set_the_centre_first(laelaps: BusSpec) -> None:
    """On a freshly started node every trajectory variable is 0: the centre sits at the hip,
    and the refusal says what to set (the docs' examples set y_cntr_traj1000 first)."""
    fresh = {s.name: {**STANDING, "y_cntr_traj1000": 0.0} for s in laelaps.slaves}
    with pytest.raises(CommandError, match=r"set the centre first, e.g. y_cntr_traj1000=599"):
        parse_command("set all b_ellipse100=4", ConsoleContext(laelaps, fresh))
    assert parse_command(
        "set all y_cntr_traj1000=599 b_ellipse100=4", ConsoleContext(laelaps, fresh)
    )


def test_a_fresh_console_knows_the_outputs_only_once_every_slave_has_them() -> None:
    """pdo_out comes one slave per message: a console that has heard from one leg must not
    check a write to all of them against outputs it does not have yet (it waits for the rest;
    console/app.py). The branched bus's couplers have no outputs and are not waited for."""
    from ether_ros.console.app import Console
    from ether_ros.ros.client import Latest

    layout = spec_of("branched.yaml")
    with_outputs = [s.name for s in layout.slaves if s.outputs]
    assert 1 < len(with_outputs) < len(layout.slaves)  # the test needs both kinds
    latest = Latest(layout=layout, outputs={with_outputs[0]: {}})
    assert not Console._outputs_known(latest)
    latest.outputs = {name: {} for name in with_outputs[:-1]}
    assert not Console._outputs_known(latest)
    latest.commanded = {with_outputs[-1]: {}}  # the node's pdo_out_timer counts too
    assert Console._outputs_known(latest)
    assert not Console._outputs_known(Latest())
