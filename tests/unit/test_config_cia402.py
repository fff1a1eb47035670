"""CiA 402 drives in the bus configuration: profile and axes checked against the ESI, the PDO
entries each axis needs, and clear refusals (docs/cia402.md)."""

from __future__ import annotations

import math
import re
from pathlib import Path

import pytest

from ether_ros.config import load_bus_config
from ether_ros.errors import ConfigError
from ether_ros.master.axis import plan_entries
from ether_ros.master.plan import layout_image

REPO = Path(__file__).resolve().parents[2]
ESI = REPO / "devices" / "servo_drive.xml"

ONE_DRIVE = """\
bus: {name: drives, interface: eth0, cycle_us: 1000}
esi: [ESI]
slaves:
  - name: drive
    device: ServoDrive2
    axes:
      - {name: j1, mode: csp, position_scale: 0.001, velocity_scale: 0.001, torque_scale: 0.01,
         position_limits: [-1.0, 1.0], velocity_limit: 2.0, torque_limit: 5.0}
      - {name: j2, mode: csv}
  - name: io
    device: GenericIO
    esi_extra: none
"""


def write(tmp_path: Path, text: str, esi: Path = ESI) -> Path:
    p = tmp_path / "bus.yaml"
    text = text.replace("    esi_extra: none\n", "")
    if "GenericIO" in text:
        text = text.replace("esi: [ESI]", f"esi: [ESI, {REPO / 'devices' / 'generic_io.xml'}]")
    p.write_text(text.replace("[ESI", f"[{esi}"))
    return p


def load_error(tmp_path: Path, text: str, esi: Path = ESI) -> str:
    with pytest.raises(ConfigError) as info:
        load_bus_config(write(tmp_path, text, esi))
    return str(info.value)


def test_arm6_has_six_axes_with_every_object_mapped() -> None:
    cfg = load_bus_config(REPO / "config" / "arm6.yaml")
    specs = cfg.axis_specs()
    assert [a.name for a in specs] == [
        "shoulder_pan", "shoulder_lift", "elbow", "wrist_1", "wrist_2", "wrist_3"
    ]  # fmt: skip
    assert [(a.slave, a.axis_index) for a in specs[:2]] == [("base_drive", 0), ("base_drive", 1)]
    for a in specs:
        assert cfg.slave(a.slave).profile == "cia402"
        assert set(a.variables) == {
            "controlword", "statusword", "mode", "mode_display", "target_position",
            "target_velocity", "target_torque", "position", "velocity", "torque", "error_code",
            "following_error",
        }  # fmt: skip
        # Axis 2's objects sit 0x800 above axis 1's.
        assert a.variables["controlword"].index == 0x6040 + 0x800 * a.axis_index
        assert a.modes == ("pp", "pv", "hm", "csp", "csv", "cst")


def test_plan_entries_put_each_object_at_its_image_byte(tmp_path: Path) -> None:
    cfg = load_bus_config(write(tmp_path, ONE_DRIVE))
    slaves = [(i, 0x1001 + i, s.name, s.layout.output_bytes, s.layout.input_bytes)
              for i, s in enumerate(cfg.slaves)]  # fmt: skip
    layout = layout_image(slaves)
    entries = plan_entries(cfg.axis_specs(), layout)
    assert [e.name for e in entries] == ["j1", "j2"]
    drive = layout.area("drive")
    j1, j2 = entries
    assert j1.map.controlword == drive.output_offset
    assert j1.map.statusword == drive.input_offset
    # The second axis's RxPDO 0x1610 follows 0x1600 (14 bytes), its TxPDO 0x1A10 follows 0x1A00.
    assert j2.map.controlword == drive.output_offset + 14
    assert j2.map.statusword == drive.input_offset + 20
    assert (j1.position_min, j1.position_max, j1.velocity_max) == (-1.0, 1.0, 2.0)
    assert j2.mode == "csv" and math.isinf(j2.position_max)
    assert (j1.on_stop, j1.fault_reset, j1.fault_backoff_ns) == (
        "quick_stop", "auto", 100_000_000
    )  # fmt: skip


BAD = [
    ("position_limits: [-1.0, 1.0]", "position_limits: [1.0, -1.0]",
     r"axes\[0\]\.position_limits: must be \[min, max\] with min <= max"),
    ("position_scale: 0.001,", "position_scale: -0.001,", r"axes\[0\]\.position_scale: must be"),
    ("velocity_scale: 0.001,", "velocity_scale: .nan,", r"axes\[0\]\.velocity_scale: must be"),
    ("torque_limit: 5.0", "torque_limit: .nan", r"axes\[0\]\.torque_limit: must be positive"),
    ("{name: j2, mode: csv}", "{name: j1, mode: csv}", r"axes\[1\]\.name: duplicate joint name"),
    ("{name: j2, mode: csv}", "{name: j2, mode: vl}", r"axes\[1\]\.mode"),
    ("    device: GenericIO\n", "    device: GenericIO\n    axes: [{name: j3}]\n",
     r"axes: axes need a CiA 402 drive: GenericIO has no ProfileNo 402"),
    ("{name: j2, mode: csv}", "{name: j2, mode: csv, speed: 3}", r"axes\[1\]\.speed: unknown key"),
]  # fmt: skip


@pytest.mark.parametrize(("old", "new", "pattern"), BAD)
def test_bad_axes_are_refused_with_the_reason(
    tmp_path: Path, old: str, new: str, pattern: str
) -> None:
    assert old in ONE_DRIVE, old
    msg = load_error(tmp_path, ONE_DRIVE.replace(old, new, 1))
    assert re.search(pattern, msg), msg


def test_a_cia402_slave_needs_axes(tmp_path: Path) -> None:
    text = ONE_DRIVE.split("    axes:")[0] + "    profile: cia402\n"
    msg = load_error(tmp_path, text)
    assert "needs axes" in msg, msg


def test_a_joint_name_is_unique_against_joints_too(tmp_path: Path) -> None:
    text = ONE_DRIVE.replace(
        "    device: GenericIO\n",
        "    device: GenericIO\n    joints: [{name: j2, position: '0x6000:01'}]\n",
    )
    msg = load_error(tmp_path, text)
    assert re.search(r"joints\[0\]\.name: duplicate joint name \(also in slave drive\)", msg), msg


def edited_esi(tmp_path: Path, old: str, new: str, count: int = -1) -> Path:
    text = ESI.read_text()
    assert old in text, old
    p = tmp_path / "servo_edited.xml"
    p.write_text(text.replace(old, new, count))
    return p


def test_a_mode_the_esi_does_not_offer_is_refused(tmp_path: Path) -> None:
    # 0x6502 = 0x80: cyclic synchronous position only.
    esi = edited_esi(tmp_path, "<DefaultData>A5030000</DefaultData>",
                     "<DefaultData>80000000</DefaultData>")  # fmt: skip
    msg = load_error(tmp_path, ONE_DRIVE, esi)
    assert re.search(r"axes\[1\]\.mode: ServoDrive2 axis 2 does not offer this mode "
                     r"\(0x6D02 supported drive modes: csp\)", msg), msg  # fmt: skip


TARGET_VELOCITY_2 = (
    "<Entry><Index>#x68FF</Index><SubIndex>0</SubIndex><BitLen>32</BitLen>"
    "<Name>Target velocity</Name><DataType>DINT</DataType></Entry>"
)
PADDING_32 = "<Entry><Index>#x0</Index><BitLen>32</BitLen></Entry>"


def test_a_missing_object_is_mapped_into_a_configurable_pdo(tmp_path: Path) -> None:
    # Axis 2's target velocity out of its RxPDO 0x1610: the drive allows PDO configuration, so
    # the loader appends it to 0x1610 and assigns the PDOs explicitly (written in PREOP).
    esi = edited_esi(tmp_path, TARGET_VELOCITY_2, PADDING_32)
    cfg = load_bus_config(write(tmp_path, ONE_DRIVE, esi))
    drive = cfg.slave("drive")
    pdo = drive.esi.pdo(0x1610)
    assert pdo is not None and (pdo.entries[-1].index, pdo.entries[-1].bit_length) == (0x68FF, 32)
    assert drive.pdo_assign is not None and drive.pdo_assign.rx == [0x1600, 0x1610]
    j2 = cfg.axis_specs()[1]
    assert j2.variables["target_velocity"].index == 0x68FF


def test_an_object_the_pdos_lack_is_named(tmp_path: Path) -> None:
    # The same, on a drive whose PDOs cannot be configured: refused, naming the object.
    esi = edited_esi(tmp_path, TARGET_VELOCITY_2, PADDING_32)
    text = esi.read_text().replace('PdoConfig="true"', 'PdoConfig="false"')
    esi.write_text(text)
    msg = load_error(tmp_path, ONE_DRIVE, esi)
    assert re.search(r"axes\[1\]: axis j2 \(mode csv\) needs object 0x68FF \(target_velocity\), "
                     r"which is not in any assigned RxPDO of ServoDrive2", msg), msg  # fmt: skip


def test_a_position_mode_needs_the_actual_position(tmp_path: Path) -> None:
    # Without 0x6064 the target before enabling cannot be the actual position.
    entry = ("<Entry><Index>#x6064</Index><SubIndex>0</SubIndex><BitLen>32</BitLen>"
             "<Name>Position actual value</Name><DataType>DINT</DataType></Entry>")  # fmt: skip
    esi = edited_esi(tmp_path, entry, PADDING_32)
    esi.write_text(esi.read_text().replace('PdoConfig="true"', 'PdoConfig="false"'))
    msg = load_error(tmp_path, ONE_DRIVE, esi)
    assert "axis j1 (mode csp) needs object 0x6064 (position)" in msg, msg


def test_a_mode_object_outside_the_pdos_is_set_in_preop(tmp_path: Path) -> None:
    # Drive with fixed PDOs without 0x6060/0x6061: the mode goes in by SDO in PREOP.
    text = ESI.read_text().replace('PdoConfig="true"', 'PdoConfig="false"')
    for idx, name, io in (("#x6060", "Modes of operation", "SINT"),
                          ("#x6061", "Modes of operation display", "SINT")):  # fmt: skip
        text = text.replace(
            f"<Entry><Index>{idx}</Index><SubIndex>0</SubIndex><BitLen>8</BitLen>"
            f"<Name>{name}</Name><DataType>{io}</DataType></Entry>",
            "<Entry><Index>#x0</Index><BitLen>8</BitLen></Entry>",
        )
    esi = tmp_path / "servo_fixed.xml"
    esi.write_text(text)
    cfg = load_bus_config(write(tmp_path, ONE_DRIVE, esi))
    drive = cfg.slave("drive")
    inits = [(i.index, i.subindex, i.data) for i in drive.sdo_init]
    assert (0x6060, 0, bytes([8])) in inits  # j1: csp
    assert "mode" not in cfg.axis_specs()[0].variables


def test_axis_extras_resolve_to_process_variables_with_si_scales(tmp_path: Path) -> None:
    from ether_ros.config.cia402 import extra_address

    assert extra_address("0x60FE:01", 1) == (0x68FE, 1)  # the second axis's own object
    assert extra_address(0x2000, 1) == (0x2000, 0)  # a vendor object as given
    assert extra_address("sixty", 0) is None
    text = ONE_DRIVE.replace(
        "{name: j2, mode: csv}",
        "{name: j2, mode: csv, velocity_scale: 0.5, extras: [{name: din, object: '0x60FD'},"
        " {name: ff, object: '0x60B1', scale: velocity}]}",
    )
    cfg = load_bus_config(write(tmp_path, text))
    j2 = cfg.axis_specs()[1]
    din, ff = j2.extras["din"], j2.extras["ff"]
    assert (din.variable.index, din.variable.direction, din.writable) == (0x68FD, "input", False)
    assert (ff.variable.index, ff.writable, ff.factor) == (0x68B1, True, 0.5)
    # Mapped into the PDOs by the master (the ESI's PDOs do not carry them).
    entries = {(v.index, v.subindex) for v in cfg.slave("drive").layout.variables}
    assert {(0x68FD, 0), (0x68B1, 0)} <= entries


@pytest.mark.parametrize(
    ("extra", "why"),
    [
        ("{name: x, object: '0x6FFF'}", "0x6FFF:00 is not in the ServoDrive2 dictionary"),
        ("{name: x, object: banana}", "is not an object address"),
        ("{name: x, object: '0x60E3:01'}", "does not mark it PDO-mappable"),
        ("{name: x, object: '0x60FD', scale: 0.0}", "must be a finite number other than 0"),
        ("{name: x, object: '0x60FD'}, {name: x, object: '0x60FE:01'}", "has this name already"),
    ],
)
def test_axis_extras_that_cannot_be_had_are_named(tmp_path: Path, extra: str, why: str) -> None:
    text = ONE_DRIVE.replace("{name: j2, mode: csv}", f"{{name: j2, mode: csv, extras: [{extra}]}}")
    msg = load_error(tmp_path, text)
    assert why.lower() in msg.lower() and "extras" in msg, msg


def test_homing_config_is_checked_against_the_drive_and_written_in_preop(tmp_path: Path) -> None:
    homing = "homing: {method: 34, speed_switch: 0.5, speed_zero: 0.1, acceleration: 2.0}"
    j1 = "torque_limit: 5.0}"
    cfg = load_bus_config(write(tmp_path, ONE_DRIVE.replace(j1, f"torque_limit: 5.0, {homing}}}")))
    inits = {(i.index, i.subindex): i.value for i in cfg.slave("drive").sdo_init}
    assert inits[(0x6098, 0)] == 34
    assert inits[(0x6099, 1)] == round(0.5 / 0.001) and inits[(0x6099, 2)] == round(0.1 / 0.001)
    assert inits[(0x609A, 0)] == round(2.0 / 0.001)
    # A speed the drive's units cannot carry is named.
    msg = load_error(
        tmp_path,
        ONE_DRIVE.replace(j1, "torque_limit: 5.0, homing: {method: 34, speed_zero: 1.0e-9}}"),
    )
    assert "homing.speed_zero" in msg, msg
    msg = load_error(
        tmp_path,
        ONE_DRIVE.replace("{name: j2, mode: csv}", "{name: j2, mode: csv, homing: {method: 1}}"),
    )
    assert "does not offer this homing method" in msg and "19, 33, 34, 35, 37" in msg, msg
