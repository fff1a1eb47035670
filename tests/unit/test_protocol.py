"""The protocol crate as Python sees it (``ether_ros._native.protocol``): the stub matches the
module, the facts that drifted between the old copies are the datasheet's, and the one object
address grammar means the same to every part that takes an address."""

from __future__ import annotations

import ast
import struct
from collections.abc import Iterator
from pathlib import Path

import pytest
from rclpy.serialization import serialize_message

from ether_ros._native import CommandTable, protocol
from ether_ros.config import load_bus_config
from ether_ros.master.bus import Bus
from ether_ros.ros import bridge
from ether_ros.ros.layout import LayoutError
from ether_ros.ros.native_commands import command_table
from ether_ros.sim.network import build_network
from ether_ros.tools.bus_inspect import InspectError, Inspector

REPO = Path(__file__).resolve().parents[2]
STUB = REPO / "python" / "ether_ros" / "_native" / "protocol.pyi"
GENERIC = REPO / "config" / "generic_io.yaml"


def _stub_namespaces() -> dict[str, set[str]]:
    tree = ast.parse(STUB.read_text())
    out: dict[str, set[str]] = {}
    for node in tree.body:
        if isinstance(node, ast.ClassDef):
            out[node.name] = {
                n.target.id
                for n in node.body
                if isinstance(n, ast.AnnAssign) and isinstance(n.target, ast.Name)
            }
    return out


def _stub_functions() -> set[str]:
    tree = ast.parse(STUB.read_text())
    return {n.name for n in tree.body if isinstance(n, ast.FunctionDef)}


def test_the_stub_lists_every_constant_and_function_of_the_module() -> None:
    stub = _stub_namespaces()
    for name, attributes in stub.items():
        runtime = getattr(protocol, name)
        if name in ("ValueCheckError", "AreaDecoder"):
            continue
        have = {k for k in vars(runtime) if not k.startswith("__")}
        assert have == attributes, f"protocol.{name}: stub and module differ"
        assert all(isinstance(getattr(runtime, k), int) for k in have)
    functions = {k for k, v in vars(protocol).items() if callable(v) and not isinstance(v, type)}
    assert functions == _stub_functions()


def test_sii_status_bits_are_the_datasheets() -> None:
    # ET1100 datasheet section II, EEPROM control/status 0x0502: bit 11 checksum error of the
    # configuration area, bit 12 not loaded, bit 13 missing acknowledge or invalid command,
    # bit 14 write without write enable, bit 15 busy. The master's copy called bit 13 the
    # checksum error and never looked at bit 11.
    assert protocol.sii.CHECKSUM_ERROR == 1 << 11
    assert protocol.sii.NOT_LOADED == 1 << 12
    assert protocol.sii.COMMAND_ERROR == 1 << 13
    assert protocol.sii.WRITE_ERROR == 1 << 14
    assert protocol.sii.BUSY == 1 << 15
    # CRC-8, polynomial 0x07, initial 0xFF, no reflection: the SII checksum in word 7.
    assert protocol.sii_checksum(b"123456789") == 0xFB


def test_al_codes_and_port_order() -> None:
    # ETG.1000.6 table 11: 0x0043 is the CoE mailbox error (the old wire crate said 0x0042,
    # which is EoE).
    assert protocol.al_code.MBX_COE == 0x0043
    assert protocol.AL_STATUS_TEXTS[0x0042] == "mailbox error (EoE)"
    assert protocol.PORT_ORDER == (0, 3, 1, 2)
    assert protocol.cmd.LRW == 12 and protocol.reg.AL_STATUS_CODE == 0x0134


SPELLINGS = ["0x7000:01", "0x7000:0x01", "7000:01", "7000:1", " 0X7000:1 "]


def test_address_grammar() -> None:
    for text in SPELLINGS:
        assert protocol.parse_address(text) == (0x7000, 1), text
    assert protocol.parse_address("0x1600:10") == (0x1600, 0x10), "the subindex is hex too"
    assert protocol.parse_address("1600:0A") == (0x1600, 0x0A)
    assert protocol.parse_address("DigitalOutput1") is None
    for out_of_range in ("28720:10", "0x10000:1", "7000:100"):
        with pytest.raises(ValueError, match="out of range"):
            protocol.parse_address(out_of_range)
    assert protocol.format_address(0x7000, 1) == "0x7000:01"


@pytest.fixture(scope="module")
def generic_bus() -> Iterator[Bus]:
    cfg = load_bus_config(GENERIC)
    with Bus.open(cfg, link=build_network(cfg)) as bus:
        yield bus


def _write_request(slave: str, variable: str, value: float) -> bytes:
    from ether_ros_msgs.msg import WriteVariable

    msg = WriteVariable()
    msg.slave, msg.position, msg.all_slaves = slave, -1, False
    msg.variable, msg.value, msg.text, msg.request_id = variable, value, "", 1
    return bytes(serialize_message(msg))


def test_7000_01_means_the_same_object_to_every_part(generic_bus: Bus) -> None:
    """Bus.write (the configuration's codec), the ROS layout, the native command path and the
    inspection tool all parse object addresses with the one grammar."""
    slave = generic_bus.slaves[0]
    layout = slave.layout
    assert layout is not None
    expected = layout.variable("0x7000:01")
    spec = bridge.bus_spec(generic_bus)
    table: CommandTable = command_table(generic_bus, spec)
    by_name = table.resolve(_write_request(slave.name, expected.name, 1.0))
    assert by_name is not None
    for text in SPELLINGS:
        assert layout.variable(text) == expected, text
        assert spec.slave(slave.name).output(text).name == expected.name, text
        native = table.resolve(_write_request(slave.name, text.strip(), 1.0))
        assert native is not None and native[0] == by_name[0], text
        generic_bus.write(slave.name, text, True)
    with pytest.raises(LayoutError, match="out of range"):
        spec.slave(slave.name).output("28720:10")
    with Inspector.open(link=build_network(load_bus_config(GENERIC)), config=str(GENERIC)) as ins:
        for text in SPELLINGS:
            ref = ins.resolve_object(slave.name, text)
            assert (ref.index, ref.subindex) == (0x7000, 1), text
        with pytest.raises(InspectError, match="out of range"):
            ins.resolve_object(slave.name, "28720:10")


def test_area_decoder_decodes_little_endian_bit_fields() -> None:
    decoder = protocol.AreaDecoder([(0, 16, "int"), (16, 1, "bool"), (17, 12, "uint"),
                                    (32, 32, "real")])  # fmt: skip
    area = struct.pack("<hHf", -5, 1 | 0xABC << 1, 1.5)
    assert decoder.decode(area) == [-5.0, 1.0, float(0xABC), 1.5]
    assert decoder.decode(area[:3])[3] == 0.0, "a field past the area decodes as 0"
    with pytest.raises(ValueError, match="cannot be decoded as a number"):
        protocol.AreaDecoder([(0, 16, "real")])


def test_value_checks() -> None:
    assert protocol.value_range("int", 8) == (-128, 127)
    assert protocol.encode_int("int", 16, -2) == 0xFFFE
    assert protocol.decode_int("int", 16, 0xFFFE) == -2
    with pytest.raises(protocol.ValueCheckError) as err:
        protocol.encode_int("uint", 8, 256)
    assert (err.value.reason, err.value.minimum, err.value.maximum) == ("out_of_range", 0, 255)
    with pytest.raises(protocol.ValueCheckError) as err:
        protocol.check_value("int", 1.5, -10, 10)
    assert err.value.reason == "not_integer"
    with pytest.raises(protocol.ValueCheckError) as err:
        protocol.check_value("real", float("nan"), -10, 10)
    assert err.value.reason == "not_finite"
