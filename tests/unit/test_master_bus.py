"""The Bus API end to end over the in-process link to the real simulator (no root needed):
bring-up to OP, process data both ways, validation before the wire, SDO in OP, stop."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest

from ether_ros.config import load_bus_config
from ether_ros.config.bus import BusConfig
from ether_ros.config.process import ProcessValueError
from ether_ros.errors import BusError
from ether_ros.master import Bus

REPO = Path(__file__).resolve().parents[2]


def _config(name: str = "laelaps.yaml") -> BusConfig:
    cfg = load_bus_config(REPO / "config" / name)
    # The in-process link takes the GIL per frame: a relaxed cycle, no RT policy needed.
    cfg.bus.cycle_us = 2000
    cfg.bus.realtime.policy = "other"
    cfg.bus.realtime.cpu = None
    cfg.bus.realtime.lock_memory = False
    cfg.bus.watchdog_ms = 0
    return cfg


def _network(cfg: BusConfig) -> object:
    from ether_ros.sim import build_network

    return build_network(cfg)


@pytest.fixture
def bus() -> Iterator[Bus]:
    cfg = _config()
    with Bus.open(cfg, link=_network(cfg), drift_frames=100) as b:
        yield b


def test_validation_happens_before_the_wire(bus: Bus) -> None:
    with pytest.raises(ProcessValueError, match="no process variable 'no_such_thing'"):
        bus.write("front_left_leg", "no_such_thing", 1)
    with pytest.raises(ProcessValueError, match="is an input"):
        bus.write("front_left_leg", "hip_angle", 1)
    with pytest.raises(ProcessValueError, match="out of range"):
        bus.write("front_left_leg", "State_Machine", 1 << 40)
    with pytest.raises(ProcessValueError, match="integer"):
        bus.write("front_left_leg", "State_Machine", "run")
    with pytest.raises(BusError, match="no slave 'left_wing'"):
        bus.write("left_wing", "State_Machine", 1)
    assert bus.outputs("front_left_leg")["State_Machine"] == 0


def test_start_to_op_exchange_and_stop(bus: Bus) -> None:
    bus.start()
    assert [s.state for s in bus.states()] == ["OP"] * 4
    assert bus.layout is not None and bus.layout.expected_wkc == 12
    bus.write("front_left_leg", "Kp100_knee", 1234)
    assert bus.read("front_left_leg", "Kp100_knee") == 1234
    inputs = bus.inputs("hind_right_leg")
    assert "hip_angle" in inputs and "knee_angle" in inputs
    samples = bus.samples()
    assert len(samples) > 0
    assert int(samples.records["wkc"][-1]) == 12
    bus.stop()
    assert [s.state for s in bus.states()] == ["INIT"] * 4


def test_identity_mismatch_is_named() -> None:
    cfg = _config()
    net = _network(cfg)
    cfg.slaves[2].product_code = 0x0BADBEEF
    message = (
        r"slave 2 \(front_left_leg\): expected vendor 0x00000A12 product 0x0BADBEEF, "
        r"found vendor 0x00000A12 product 0x00A986FD"
    )
    with pytest.raises(BusError, match=message):
        Bus.open(cfg, link=net)
