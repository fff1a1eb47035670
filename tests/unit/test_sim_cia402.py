"""The simulator's CiA 402 drive from the Python side: the default model for profile-402 ESIs,
its parameters, and the ``drive_fault`` fault (control socket validation, the command line,
and the errors of the native model)."""
# ruff: noqa: E501  (tables of requests read best one case per line)

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from ether_ros._native import DriveFault
from ether_ros.config.bus import default_sim_device
from ether_ros.config.esi import load_esi
from ether_ros.config.from_esi import bus_config_for_esi
from ether_ros.sim.control import ControlError, validate_request
from ether_ros.sim.spec import network_specs

REPO = Path(__file__).resolve().parents[2]
SERVO = REPO / "devices" / "servo_drive.xml"
SLAVES = ["servo0", "servo1"]


def test_profile_402_devices_run_the_cia402_model() -> None:
    for d in load_esi(SERVO):
        assert default_sim_device(d) == "cia402"
    # Other devices keep theirs; a 402 profile in any ESI selects the drive model.
    assert default_sim_device(load_esi(REPO / "devices" / "generic_io.xml")[0]) == "generic_io"
    corpus = load_esi(REPO / "tests" / "data" / "esi" / "servo_vendor_style.xml")[0]
    assert default_sim_device(corpus) == "cia402"
    cfg = bus_config_for_esi(SERVO, "ServoDrive2", 2, interface="veth-x")
    assert [s.device for s in network_specs(cfg)] == ["cia402", "cia402"]


@pytest.mark.parametrize(
    ("request_", "error"),
    [
        ({"error": "overheat"}, r"fault drive_fault: DriveFault.error: \"overheat\" is not one of over_current, encoder, under_voltage, following_error"),
        ({"error": 3}, r"fault drive_fault: .*while processing 'error'"),
        ({"error": "encoder", "axis": 0}, r"DriveFault.axis: 0 is outside 1..=8"),
        ({"error": "encoder", "axis": 9}, r"DriveFault.axis: 9 is outside 1..=8"),
        ({"error": "encoder", "axis": 1.5}, r"while processing 'axis'"),
        ({"axis": 1}, r"fault drive_fault: DriveFault.__new__\(\) missing 1 required keyword argument: 'error'"),
        ({"error": "encoder", "kind2": 1}, r"DriveFault.__new__\(\) got an unexpected keyword argument 'kind2'"),
        ({"error": "encoder", "slave": "servo7"}, r"slave: no slave named 'servo7'"),
    ],
)  # fmt: skip
def test_control_socket_validates_drive_fault(request_: dict[str, Any], error: str) -> None:
    req = {"op": "fault", "kind": "drive_fault", "slave": 0, **request_}
    with pytest.raises(ControlError, match=error):
        validate_request(req, SLAVES)


def test_control_socket_accepts_drive_fault_with_default_axis() -> None:
    req = {"op": "fault", "kind": "drive_fault", "slave": "servo1", "error": "encoder"}
    op, kind, fault = validate_request(req, SLAVES)
    assert (op, kind, fault) == ("fault", "drive_fault", DriveFault(slave=1, error="encoder"))
    assert fault.axis == 1  # DriveFault's default, the one place it is written


def _parse(argv: list[str]) -> Any:
    from ether_ros.cli.main import build_parser

    return build_parser().parse_args(["sim-fault", "--interface", "veth9", *argv])


def test_sim_fault_command_line_builds_drive_fault() -> None:
    from ether_ros.cli.sim import fault_request

    req = fault_request(_parse(["drive-fault", "servo1", "encoder", "--axis", "2"]))
    assert req == {
        "op": "fault",
        "kind": "drive_fault",
        "slave": "servo1",
        "error": "encoder",
        "axis": 2,
    }
    validate_request(req, SLAVES)
    # Without --axis the request leaves it out and DriveFault's default applies.
    req = fault_request(_parse(["drive-fault", "servo1", "encoder"]))
    assert "axis" not in req
    assert validate_request(req, SLAVES)[2] == DriveFault(slave=1, error="encoder", axis=1)


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["drive-fault", "0", "overheat"], "argument error: unknown drive fault 'overheat' (known: over_current, encoder, under_voltage, following_error)"),
        (["drive-fault", "0", "encoder", "--axis", "0"], "argument --axis: axis must be 1..8, got 0"),
        (["drive-fault", "0", "encoder", "--axis", "two"], "argument --axis: axis must be a number 1..8, got 'two'"),
    ],
)  # fmt: skip
def test_sim_fault_command_line_refuses_bad_drive_fault(
    argv: list[str], message: str, capsys: pytest.CaptureFixture[str]
) -> None:
    with pytest.raises(SystemExit) as exc:
        _parse(argv)
    assert exc.value.code == 2
    assert message in capsys.readouterr().err


@pytest.fixture
def servo_net() -> Any:
    from ether_ros.sim.network import build_network

    cfg = bus_config_for_esi(SERVO, "ServoDrive2", 1, interface="veth-x")
    return build_network(cfg)


def test_native_drive_fault_errors_name_the_problem(servo_net: Any) -> None:
    with pytest.raises(ValueError, match=r"no axis 3 \(this drive has axes 1..=2\)"):
        servo_net.inject(DriveFault(slave=0, error="encoder", axis=3))
    with pytest.raises(ValueError, match=r"DriveFault.error: \"overheat\" is not one of"):
        servo_net.inject(DriveFault(slave=0, error="overheat"))
    with pytest.raises(TypeError, match=r"missing 1 required keyword argument: 'error'"):
        servo_net.inject(DriveFault(slave=0))  # type: ignore[call-arg]
    with pytest.raises(ValueError, match=r"no slave at position 5|slave 5"):
        servo_net.inject(DriveFault(slave=5, error="encoder"))
    servo_net.inject(DriveFault(slave=0, error="encoder", axis=2))


def test_native_drive_fault_on_a_device_without_faults() -> None:
    from ether_ros.sim.network import build_network

    cfg = bus_config_for_esi(REPO / "devices" / "generic_io.xml", None, 1, interface="veth-x")
    net = build_network(cfg)
    with pytest.raises(ValueError, match=r"no injectable faults \(got 'encoder'\)"):
        net.inject(DriveFault(slave=0, error="encoder"))


def test_probe_reports_each_axis_in_si_units(servo_net: Any) -> None:
    probe = servo_net.probe(0)
    assert probe["axes"] == 2.0
    for axis in (1, 2):
        for name in ("position_rad", "velocity_rad_s", "torque_nm", "state", "mode"):
            assert f"axis{axis}_{name}" in probe
        assert probe[f"axis{axis}_state"] == 0.0  # not ready to switch on: no step ran yet
        # 0.6 Nm motor peak through a 50:1 gear.
        assert probe[f"axis{axis}_torque_limit_nm"] == pytest.approx(30.0)
