"""Simulator front: specs from the config, and the control socket's request validation."""
# ruff: noqa: E501  (tables of requests read best one case per line)

from __future__ import annotations

import json
import socket
from pathlib import Path
from typing import Any

import pytest

from ether_ros._native import Clear, DriftStep, Drop, Link, Reset
from ether_ros.config import load_bus_config, parse_sii
from ether_ros.sim.control import ControlError, ControlServer, request, validate_request
from ether_ros.sim.spec import SERIAL_BASE, network_specs

REPO = Path(__file__).resolve().parents[2]
SLAVES = ["hind_right_leg", "hind_left_leg", "front_left_leg", "front_right_leg"]


def test_laelaps_specs() -> None:
    cfg = load_bus_config(REPO / "config" / "laelaps.yaml")
    specs = network_specs(cfg)
    assert [s.name for s in specs] == SLAVES
    s0 = specs[0]
    assert (s0.vendor_id, s0.product_code, s0.device) == (
        0x0A12,
        0x00A986FD,
        "laelaps_leg",
    )
    assert s0.dc_supported and s0.dc_required
    m = s0.mailbox
    assert m is not None
    assert (m.rx_offset, m.rx_size, m.tx_offset, m.tx_size) == (0x1000, 128, 0x1080, 128)
    assert s0.serial == SERIAL_BASE and specs[3].serial == SERIAL_BASE + 3
    assert s0.drift_ppm == 12.0 and s0.delay_ns == 500
    info = parse_sii(s0.sii)
    assert info.checksum_ok and info.serial == SERIAL_BASE and info.vendor_id == 0x0A12
    entries = {(e[0], e[1]): e for e in s0.entries}
    state = entries[(0x7000, 1)]
    assert state[2:7] == ("State_Machine", 1, 1, "rw", True)
    assert entries[(0x1008, 0)][7] == b"LaelapsII_Leg"
    assert (0x1018, "Identity", 9) in s0.objects
    for e in s0.entries:
        assert len(e[7]) == (e[4] + 7) // 8


def test_generic_io_spec_device_default() -> None:
    cfg = load_bus_config(REPO / "config" / "mixed.yaml")
    specs = network_specs(cfg)
    assert [s.device for s in specs] == ["laelaps_leg"] * 4 + ["generic_io"]
    assert not specs[4].dc_required


@pytest.mark.parametrize(
    ("req", "expected"),
    [
        ({"op": "fault", "kind": "drop", "rate": 0.5}, ("fault", "drop", Drop(rate=0.5, burst=1))),
        ({"op": "fault", "kind": "reset", "slave": "front_left_leg"}, ("fault", "reset", Reset(slave=2))),
        ({"op": "fault", "kind": "reset", "slave": "3"}, ("fault", "reset", Reset(slave=3))),
        ({"op": "fault", "kind": "link", "up": False}, ("fault", "link", Link(up=False))),
        ({"op": "fault", "kind": "drift_step", "slave": 1, "ppm": -20}, ("fault", "drift_step", DriftStep(slave=1, ppm=-20.0))),
        ({"op": "fault", "kind": "clear"}, ("fault", "clear", Clear())),
        ({"op": "slave_info", "slave": "hind_left_leg"}, ("slave_info", "", 1)),
        ({"op": "stats"}, ("stats", "", None)),
    ],
)  # fmt: skip
def test_valid_requests(req: dict[str, Any], expected: tuple[str, str, Any]) -> None:
    assert validate_request(req, SLAVES) == expected


@pytest.mark.parametrize(
    ("req", "pattern"),
    [
        ([1, 2], "JSON object"),
        ({"op": "shell", "cmd": "rm -rf /"}, "unknown op 'shell'"),
        ({"op": "fault", "kind": "explode"}, "unknown fault 'explode'"),
        ({"op": "fault", "kind": "drop"}, r"fault drop: Drop.__new__\(\) missing 1 required keyword argument: 'rate'"),
        ({"op": "fault", "kind": "drop", "rate": 2}, r"fault drop: Drop.rate: 2 is outside 0..=1"),
        ({"op": "fault", "kind": "drop", "rate": "0.1"}, "while processing 'rate'"),
        ({"op": "fault", "kind": "drop", "rate": 0.1, "burst": 1.5}, "while processing 'burst'"),
        ({"op": "fault", "kind": "drop", "rate": True}, "rate: expected a number, got True"),
        ({"op": "fault", "kind": "drop", "rate": 0.1, "x": 1}, r"Drop.__new__\(\) got an unexpected keyword argument 'x'"),
        ({"op": "fault", "kind": "reset", "slave": "tail"}, "no slave named 'tail'"),
        ({"op": "fault", "kind": "reset", "slave": 9}, r"no slave at position 9 \(0..3\)"),
        ({"op": "fault", "kind": "refuse_op", "slave": 0, "on": 1}, "while processing 'on'"),
        ({"op": "probe"}, "exactly one argument: slave"),
        ({"op": "stats", "all": True}, "stats takes no arguments"),
    ],
)  # fmt: skip
def test_invalid_requests(req: Any, pattern: str) -> None:
    with pytest.raises(ControlError, match=pattern):
        validate_request(req, SLAVES)


def test_socket_round_trip(tmp_path: Path) -> None:
    calls: list[tuple[str, str, Any]] = []

    def handler(op: str, kind: str, args: Any) -> Any:
        calls.append((op, kind, args))
        if op == "stats":
            return {"frames": 7}
        if kind == "corrupt":
            raise ValueError("core refused")
        return None

    path = tmp_path / "ctl.sock"
    server = ControlServer(path, SLAVES, handler)
    server.start()
    try:
        assert request(path, {"op": "stats"}) == {"frames": 7}
        assert request(path, {"op": "fault", "kind": "reset", "slave": "hind_left_leg"}) is None
        with pytest.raises(ControlError, match="unknown fault"):
            request(path, {"op": "fault", "kind": "nope"})
        with pytest.raises(ControlError, match="simulator: core refused"):
            request(path, {"op": "fault", "kind": "corrupt", "rate": 0.1})
        # Garbage on the wire gets an error line, and the connection stays usable.
        with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as s:
            s.connect(str(path))
            f = s.makefile("rwb")
            f.write(b"{not json\n")
            f.flush()
            assert json.loads(f.readline())["ok"] is False
            f.write(b'{"op": "stats"}\n')
            f.flush()
            assert json.loads(f.readline()) == {"ok": True, "result": {"frames": 7}}
            f.close()
        # A second server on the same path is refused while the first one lives.
        with pytest.raises(ControlError, match="already running"):
            ControlServer(path, SLAVES, handler)
    finally:
        server.close()
    assert not path.exists()
    assert calls[:2] == [("stats", "", None), ("fault", "reset", Reset(slave=1))]
    with pytest.raises(ControlError, match="no simulator listening"):
        request(path, {"op": "stats"})


@pytest.mark.parametrize(
    ("argv", "expected"),
    [
        (["drop", "--rate", "0.01"], {"op": "fault", "kind": "drop", "rate": 0.01}),  # Drop's burst
        (["drop", "--rate", "0.01", "--burst", "3"], {"op": "fault", "kind": "drop", "rate": 0.01, "burst": 3}),
        (["corrupt", "--rate", "0.5", "--bytes", "2"], {"op": "fault", "kind": "corrupt", "rate": 0.5, "bytes": 2}),
        (["delay", "--us", "300"], {"op": "fault", "kind": "delay", "us": 300}),
        (["reset", "hind_left_leg"], {"op": "fault", "kind": "reset", "slave": "hind_left_leg"}),
        (["refuse-op", "2", "--off"], {"op": "fault", "kind": "refuse_op", "slave": "2", "on": False}),
        (["stall-mailbox", "0"], {"op": "fault", "kind": "stall_mailbox", "slave": "0", "on": True}),
        (["link", "down"], {"op": "fault", "kind": "link", "up": False}),
        (["link", "up", "--at", "3"], {"op": "fault", "kind": "link", "up": True, "at": "3"}),
        (["drift-step", "front_left_leg", "-25"], {"op": "fault", "kind": "drift_step", "slave": "front_left_leg", "ppm": -25.0}),
        (["clear"], {"op": "fault", "kind": "clear"}),
        (["stats"], {"op": "stats"}),
        (["probe", "1"], {"op": "probe", "slave": "1"}),
    ],
)  # fmt: skip
def test_sim_fault_command_line_builds_valid_requests(
    argv: list[str], expected: dict[str, Any]
) -> None:
    from ether_ros.cli.main import build_parser
    from ether_ros.cli.sim import fault_request

    args = build_parser().parse_args(["sim-fault", "--interface", "veth9", *argv])
    req = fault_request(args)
    assert req == expected
    validate_request(req, SLAVES)  # what the command line builds, the server accepts


def test_sim_fault_without_simulator_is_one_line_error(tmp_path: Path, capsys: Any) -> None:
    from ether_ros.cli.main import main

    code = main(["sim-fault", "--control", str(tmp_path / "none.sock"), "clear"])
    assert code == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("ether-ros sim-fault: error: no simulator listening on")
    assert "\n" not in err


def test_identity_object_carries_the_serial() -> None:
    cfg = load_bus_config(REPO / "config" / "laelaps.yaml")
    for pos, spec in enumerate(network_specs(cfg)):
        entries = {(e[0], e[1]): e[7] for e in spec.entries}
        assert int.from_bytes(entries[(0x1018, 4)], "little") == SERIAL_BASE + pos
        assert int.from_bytes(entries[(0x1018, 1)], "little") == 0x0A12
