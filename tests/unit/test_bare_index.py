"""One rule for an object index written without prefix: ``6040`` is 0x6040 everywhere — the
YAML configuration, a CiA 402 extra's object, the CLI's register addresses, the console's and
the ROS interface's object addresses. Every entry point goes through the protocol crate's
grammar (``protocol.parse_index`` / ``parse_subindex`` / ``parse_address``); there is no
decimal form."""

from __future__ import annotations

from pathlib import Path

import pytest

from bus_specs import spec_of
from ether_ros._native import protocol
from ether_ros.config import load_bus_config
from ether_ros.config.cia402 import extra_address
from ether_ros.console.commands import CommandError, ConsoleContext, SdoRead, parse_command
from ether_ros.errors import ConfigError, EtherRosError
from ether_ros.ros import bridge
from ether_ros.tools.bus_inspect import InspectError, parse_register

REPO = Path(__file__).resolve().parents[2]

IO_BUS = """\
bus: {name: io_bus, interface: eth0, cycle_us: 1000}
esi: [DEVICES/generic_io.xml]
slaves:
  - name: io
    device: GenericIO
    pdo_assign: {rx: [RX], tx: [0x1A00, 0x1A01]}
    sdo_init: [{index: INDEX, subindex: SUB, value: -5}]
"""


def io_bus(tmp_path: Path, rx: str, index: str, sub: str) -> Path:
    p = tmp_path / "bus.yaml"
    text = IO_BUS.replace("DEVICES", str(REPO / "devices"))
    p.write_text(text.replace("RX", rx).replace("INDEX", index).replace("SUB", sub))
    return p


def test_the_protocol_rule() -> None:
    for text in ("6040", "0x6040", "0X6040", " 6040 "):
        assert protocol.parse_index(text) == 0x6040, text
    assert protocol.parse_subindex("10") == 0x10
    for bad in ("", "60 40", "-1", "1_000", "6040:00", "#x6040"):
        with pytest.raises(ValueError, match="hexadecimal"):
            protocol.parse_index(bad)
    with pytest.raises(ValueError, match="out of range"):
        protocol.parse_index("10000")
    with pytest.raises(ValueError, match="out of range"):
        protocol.parse_subindex("100")


@pytest.mark.parametrize(
    ("rx", "index", "sub"),
    [
        ("0x1600", "0x7010", "1"),  # the prefixed spelling (a YAML number)
        ('"1600"', '"7010"', '"1"'),  # text without prefix: hexadecimal, never decimal
        ('"#x1600"', '"#x7010"', '"0x01"'),  # the ESI's spelling
        ("5632", "28688", "1"),  # a YAML number as yaml.safe_dump writes 0x1600 and 0x7010
    ],
)
def test_yaml_indices_are_hexadecimal(tmp_path: Path, rx: str, index: str, sub: str) -> None:
    io = load_bus_config(io_bus(tmp_path, rx, index, sub)).slave("io")
    assert io.layout.rx_pdos == (0x1600,)
    assert [(i.index, i.subindex) for i in io.sdo_init] == [(0x7010, 1)]


def test_yaml_subindex_10_is_sixteen(tmp_path: Path) -> None:
    """``subindex: "10"`` is 0x10, as in the address ``0x7010:10``; GenericIO's 0x7010 has
    no subindex 16, so the load names the address it looked for."""
    with pytest.raises(ConfigError, match="0x7010:10"):
        load_bus_config(io_bus(tmp_path, "0x1600", "0x7010", '"10"'))


@pytest.mark.parametrize(
    ("rx", "index", "why"),
    [
        ("0x1600", '"10000"', "index out of range"),
        ("0x1600", "banana", "is not an index"),
        ("16G0", "0x7010", "is not an index"),
        ("0x1600", '"1_000"', "is not an index"),
    ],
)
def test_yaml_indices_refused_name_the_field(tmp_path: Path, rx: str, index: str, why: str) -> None:
    with pytest.raises(ConfigError, match=why):
        load_bus_config(io_bus(tmp_path, rx, index, "1"))


def test_extras_objects_read_the_same() -> None:
    assert extra_address("60FD", 0) == extra_address("0x60FD", 0) == (0x60FD, 0)
    assert extra_address("60FE:01", 1) == (0x68FE, 1)
    assert extra_address("2000", 0) == (0x2000, 0)  # was int("2000", 0): 0x07D0
    assert extra_address("sixty", 0) is None


def test_cli_register_addresses() -> None:
    assert parse_register("0x0130") == parse_register("0130") == parse_register("130") == 0x130
    assert parse_register("910") == 0x0910
    with pytest.raises(InspectError, match=r"register address: .*hexadecimal"):
        parse_register("0o17")
    with pytest.raises(InspectError, match="out of range"):
        parse_register("12345")


def test_console_and_ros_addresses() -> None:
    spec = spec_of("laelaps.yaml")
    ctx = ConsoleContext(spec, {})
    cmd = parse_command("sdo read front_left_leg 7030:3 UINT", ctx)
    assert isinstance(cmd, SdoRead) and (cmd.index, cmd.subindex) == (0x7030, 3)
    with pytest.raises(CommandError, match="out of range"):
        parse_command("sdo read front_left_leg 28720:10 UINT", ctx)
    # A write_variables / pdo_listener request names its variable by address the same way.
    [(_slave, var, _value)] = bridge.resolve_write(
        spec, "front_left_leg", 0, False, "7030:01", 5.0, ""
    )
    assert (var.index, var.subindex, var.name) == (0x7030, 1, "x_cntr_traj1000")
    # 28720 is 0x7030 in decimal: refused, never read as 0x7030:01.
    with pytest.raises(EtherRosError, match="28720:1"):
        bridge.resolve_write(spec, "front_left_leg", 0, False, "28720:1", 5.0, "")
