"""Process variables: bit layout, lookup, and the value codec with its range errors."""
# ruff: noqa: E501  (tables of bad inputs read best one case per line)

from __future__ import annotations

from pathlib import Path

import pytest

from ether_ros.config import ProcessLayout, ProcessValueError, load_esi
from ether_ros.config.process import read_bits, write_bits
from ether_ros.errors import ConfigError, EtherRosError

REPO = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def leg() -> ProcessLayout:
    (dev,) = load_esi(REPO / "devices" / "laelaps_ii_leg.xml")
    return ProcessLayout.for_device(dev)


def test_offsets_follow_table_4_1(leg: ProcessLayout) -> None:
    offsets = {v.name: (v.bit_offset, v.bit_length) for v in leg.outputs}
    assert offsets["State_Machine"] == (0, 1)
    assert offsets["Button2"] == (7, 1)
    assert offsets["Transition_time"] == (8, 8)
    assert offsets["Desired_x_value"] == (16, 32)
    assert offsets["FilterBandwidth"] == (48, 16)
    assert offsets["FlatnessParam100"] == (288, 16)
    assert leg.output_bytes == 38
    assert leg.variable("velocity_hip1000").byte_offset == 18
    assert leg.input_bytes == 22


def test_write_read_round_trip(leg: ProcessLayout) -> None:
    area = leg.pack_outputs(
        {"State_Machine": True, "Red_LED": 1, "Transition_time": -3, "y_cntr_traj1000": 599,
         "0x7030:06": 180, "Desired_x_value": -2_000_000_000, "FilterBandwidth": 65535}
    )  # fmt: skip
    assert area[0] == 0b0010_0001
    assert area[1] == 0xFD
    assert leg.read(area, "State_Machine") is True
    assert leg.read(area, "Red_LED") is True and leg.read(area, "Blue_LED") is False
    assert leg.read(area, "Transition_time") == -3
    assert leg.read(area, "phase_deg") == 180
    assert leg.read(area, "Desired_x_value") == -2_000_000_000
    assert leg.read(area, "FilterBandwidth") == 65535
    values = leg.unpack(area, "output")
    assert values["y_cntr_traj1000"] == 599 and values["Button1"] is False


def test_lookup_by_key_and_errors(leg: ProcessLayout) -> None:
    assert leg.variable("0x6010:01").name == "hip_angle"
    assert leg.variable("0x6010:1") is leg.variable("hip_angle")
    assert leg.has("knee_angle") and not leg.has("elbow")
    with pytest.raises(ProcessValueError, match="no process variable 'elbow'"):
        leg.variable("elbow")


@pytest.mark.parametrize(
    ("name", "value", "pattern"),
    [
        ("Transition_time", 128, r"Transition_time \(0x7000:09, int8\): 128 is out of range for int8 \[-128, 127\]"),
        ("FilterBandwidth", -1, r"FilterBandwidth \(0x7012:01, uint16\): -1 is out of range"),
        ("State_Machine", 2, r"State_Machine \(0x7000:01, bool\): bool needs true/false or 0/1"),
        ("a_ellipse100", 1.5, r"a_ellipse100 \(0x7030:03, int16\): int16 needs an integer, got 1.5"),
        ("a_ellipse100", "5", r"int16 needs an integer, got '5'"),
    ],
)  # fmt: skip
def test_encode_errors_name_variable_type_and_range(
    leg: ProcessLayout, name: str, value: object, pattern: str
) -> None:
    area = bytearray(leg.output_bytes)
    with pytest.raises(ProcessValueError, match=pattern) as info:
        leg.write(area, name, value)
    assert isinstance(info.value, EtherRosError) and isinstance(info.value, ValueError)
    assert area == bytearray(leg.output_bytes)  # nothing written


def test_pack_outputs_rejects_inputs_and_bad_base(leg: ProcessLayout) -> None:
    with pytest.raises(ProcessValueError, match="is an input"):
        leg.pack_outputs({"hip_angle": 1})
    with pytest.raises(ProcessValueError, match="output area is 38 bytes, base has 3"):
        leg.pack_outputs({}, base=b"abc")


def test_assignment_override_and_unknown_pdo() -> None:
    (gio,) = load_esi(REPO / "devices" / "generic_io.xml")
    only_analog = ProcessLayout.for_device(gio, rx_pdos=[0x1601], tx_pdos=[])
    assert only_analog.output_bytes == 4 and only_analog.input_bytes == 0
    assert only_analog.variable("AnalogOutput1").bit_offset == 0
    with pytest.raises(ConfigError, match="GenericIO has no RxPDO 0x1a00"):
        ProcessLayout.for_device(gio, rx_pdos=[0x1A00])


def test_bit_helpers_unaligned() -> None:
    area = bytearray(3)
    write_bits(area, 5, 12, 0xABC)
    assert read_bits(area, 5, 12) == 0xABC
    assert read_bits(area, 0, 5) == 0 and read_bits(area, 17, 7) == 0
    with pytest.raises(ProcessValueError, match="too short"):
        read_bits(area, 20, 8)
