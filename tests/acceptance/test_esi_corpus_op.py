"""Every device of the ESI corpus (tests/data/esi), and our servo drives
(devices/servo_drive.xml), runs on the simulator without a bus config
(``ether-ros sim --esi FILE --device TYPE --count 2``, its own process and network namespace)
and reaches OP under our master, opened with the same ESI (`bus_config_for_esi`). The generic
``loopback`` model copies outputs to matching inputs, so a value written by the master comes
back in the inputs: process data really flows through both ends. A CiA 402 device (profile 402)
runs the ``cia402`` drive model instead: its statusword answers the controlword."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from ether_ros.config import types as dt
from ether_ros.config.bus import default_sim_device
from ether_ros.config.from_esi import bus_config_for_esi
from ether_ros.errors import ConfigError
from ether_ros.master import Bus
from ether_ros.sim.proof import SimProcess
from ether_ros.sim.spec import loopback_pairs
from ether_ros.testing.netns import VethPair
from ether_ros.testing.wait import wait_for
from user_commands import ether_ros

pytestmark = pytest.mark.netns

CORPUS = Path(__file__).resolve().parents[1] / "data" / "esi"
SERVO = Path(__file__).resolve().parents[2] / "devices" / "servo_drive.xml"
DEVICES = [
    (str(SERVO), "ServoDrive1"),
    (str(SERVO), "ServoDrive2"),
    ("servo_vendor_style.xml", "CorpusServo"),
    ("multi_device_latin1.xml", "CorpusDIO8"),
    ("multi_device_latin1.xml", "CorpusDIO16"),
    ("analog_utf16.xml", "CorpusAnalog2"),
    ("modular_coupler.xml", "CorpusModular"),
    ("dictfile_counter.xml", "CorpusCounter"),
]


def _value_for(type_code: int, bits: int) -> int | bool:
    if type_code == dt.BOOL.code:
        return True
    return (0x5A5A5A5A5A5A5A5A & ((1 << (bits - 1)) - 1)) or 1


@pytest.mark.parametrize(("file", "device"), DEVICES)
def test_corpus_device_reaches_op_and_loops_back(file: str, device: str) -> None:
    esi = CORPUS / file
    sim_args = ["--esi", str(esi), "--device", device, "--count", "2"]
    with (
        VethPair.create(netns=True) as veth,
        SimProcess(None, veth.slave, veth.netns, sim_args) as sim,
    ):
        assert sim.ready_line.endswith(f"2 slaves on {veth.slave} ready")
        cfg = bus_config_for_esi(esi, device, 2, interface=veth.master)
        with Bus.open(cfg) as bus:
            bus.start()
            assert [s.state for s in bus.states()] == ["OP", "OP"]
            slave = cfg.slaves[1]
            layout = slave.layout
            if default_sim_device(slave.esi) == "cia402":
                _drive_answers_shutdown(bus, slave.name, layout)
                return
            pairs = loopback_pairs(slave.esi)
            assert pairs, f"{device}: no output has an input partner"
            out_var = next(v for v in layout.outputs if (v.index, v.subindex) == pairs[0][:2])
            in_var = next(v for v in layout.inputs if (v.index, v.subindex) == pairs[0][2:])
            value = _value_for(out_var.data_type, out_var.bit_length)
            bus.write(slave.name, out_var.name, value)
            wait_for(
                f"{device}: {in_var.name} to echo",
                lambda: bus.read(slave.name, in_var.name) == value,
                timeout=10,
            )


def _drive_answers_shutdown(bus: Bus, slave: str, layout: Any) -> None:
    """Controlword "shutdown" (0x06) takes the drive to Ready to switch on (0x21 under 0x6F)."""
    control = next(v for v in layout.outputs if v.index == 0x6040)
    status = next(v for v in layout.inputs if v.index == 0x6041)
    # By key: a multi-axis drive names the objects of every axis alike.
    bus.write(slave, control.key, 0x06)
    wait_for(
        f"{slave}: the statusword to show the shutdown",
        lambda: int(bus.read(slave, status.key)) & 0x6F == 0x21,
        timeout=10,
    )


def test_sim_esi_refuses_a_missing_device_with_the_choices(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match=r"holds several devices \(CorpusDIO16, CorpusDIO8\)"):
        bus_config_for_esi(CORPUS / "multi_device_latin1.xml")
    with pytest.raises(ConfigError, match=r"no device 'Nope' \(it has: CorpusServo\)"):
        bus_config_for_esi(CORPUS / "servo_vendor_style.xml", "Nope")
    with pytest.raises(ConfigError, match=r"--count must be 1..64"):
        bus_config_for_esi(CORPUS / "servo_vendor_style.xml", count=0)


@pytest.mark.parametrize(
    ("args", "message"),
    [
        ((), "give a bus configuration or --esi FILE (one of them)"),
        (("config/laelaps.yaml", "--esi", "x.xml"), "give a bus configuration or --esi FILE"),
        (("config/laelaps.yaml", "--count", "3"), "--device and --count go with --esi"),
        (
            ("--esi", str(CORPUS / "servo_vendor_style.xml")),
            "'ether-ros sim --esi' needs -i/--interface",
        ),
        (
            ("--esi", str(CORPUS / "multi_device_latin1.xml"), "--interface", "lo"),
            "holds several devices (CorpusDIO16, CorpusDIO8): give --device",
        ),
    ],
)
def test_sim_command_refuses_bad_arguments_with_one_line(
    args: tuple[str, ...], message: str
) -> None:
    done = ether_ros("sim", *args, timeout=60)
    assert done.returncode != 0
    assert message in done.stderr and "Traceback" not in done.stderr
