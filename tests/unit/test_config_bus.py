"""Bus configuration loading: the shipped configs, and clear errors for bad input."""

from __future__ import annotations

import re
import textwrap
from pathlib import Path

import pytest

from ether_ros.config import load_bus_config
from ether_ros.errors import ConfigError

REPO = Path(__file__).resolve().parents[2]
DEVICES = REPO / "devices"

GOOD = """\
bus:
  name: test_bus
  interface: eth0
  cycle_us: 400
  dc: {enabled: true, mode: ref_follows_master, reference: 0, sync0_shift_us: 55}
esi: [DEVICES]
slaves:
  - name: leg_a
    position: 0
    vendor_id: 0x00000A12
    product_code: "0x00A986FD"
    device: LaelapsII_Leg
    safe_outputs: {State_Machine: 0, Blue_LED: true}
    joints:
      - {name: a_hip, position: hip_angle, position_scale: 0.000174533,
         velocity: velocity_hip1000, velocity_scale: 0.001}
  - name: leg_b
    position: 1
    vendor_id: 0x00000A12
    product_code: 0x00A986FD
  - name: io
    position: 2
    device: GenericIO
    pdo_assign: {rx: ["0x1600"], tx: [0x1A00, 0x1A01]}
    sdo_init: [{index: 0x7010, subindex: 1, value: -5}]
"""


def write(tmp_path: Path, text: str) -> Path:
    p = tmp_path / "bus.yaml"
    p.write_text(text.replace("DEVICES", str(DEVICES)))
    return p


def test_shipped_laelaps_config() -> None:
    cfg = load_bus_config(REPO / "config" / "laelaps.yaml", interface="veth7")
    assert cfg.bus.interface == "veth7"
    assert cfg.bus.cycle_us == 400
    assert cfg.bus.dc.sync0_shift_us == 55
    assert [s.name for s in cfg.slaves] == [
        "hind_right_leg",
        "hind_left_leg",
        "front_left_leg",
        "front_right_leg",
    ]
    for i, s in enumerate(cfg.slaves):
        assert s.position == i
        assert (s.vendor_id, s.product_code) == (0x00000A12, 0x00A986FD)
        assert s.esi.type_name == "LaelapsII_Leg"
        assert (s.layout.output_bytes, s.layout.input_bytes) == (38, 22)
        assert s.safe_output_image == bytes(38)
        assert {j.name.split("_")[1] for j in s.joints} == {"hip", "knee"}
        assert s.sim_device == "laelaps_leg"


@pytest.mark.parametrize("name", ["generic_io.yaml", "mixed.yaml", "laelaps16.yaml"])
def test_other_shipped_configs_load(name: str) -> None:
    cfg = load_bus_config(REPO / "config" / name)
    assert cfg.slaves
    assert len({s.name for s in cfg.slaves}) == len(cfg.slaves)


def test_good_config_resolves_everything(tmp_path: Path) -> None:
    cfg = load_bus_config(write(tmp_path, GOOD))
    a, b, io = cfg.slaves
    assert b.esi is a.esi or b.esi.type_name == "LaelapsII_Leg"
    assert b.device is None and b.esi.type_name == "LaelapsII_Leg"
    # State_Machine is bit 0, Blue_LED bit 4 of the first output byte.
    assert a.safe_output_image[0] == 0b0001_0000
    assert io.device == "GenericIO" and io.vendor_id == 0x00000A12
    assert io.layout.rx_pdos == (0x1600,) and io.layout.output_bytes == 1
    assert io.layout.input_bytes == 5
    assert io.sdo_init[0].data == (-5).to_bytes(2, "little", signed=True)
    assert io.sdo_init[0].type == "int16"
    assert cfg.slave("io") is io
    with pytest.raises(ConfigError, match="no slave named 'nope'"):
        cfg.slave("nope")


def test_positions_default_to_list_order(tmp_path: Path) -> None:
    text = GOOD.replace("    position: 0\n", "").replace("    position: 1\n", "")
    text = text.replace("    position: 2\n", "")
    cfg = load_bus_config(write(tmp_path, text))
    assert [s.position for s in cfg.slaves] == [0, 1, 2]


BAD = [
    # (replace this, with this, expected message regex incl. key path, expected line or None)
    ("  cycle_us: 400", "  cycle_us: 400\n  cycle_time: 3", r"bus\.cycle_time: unknown key", 5),
    ("  cycle_us: 400", "  cycle_us: 5", r"bus\.cycle_us: .*greater than or equal to 20.*got 5", 4),
    ("  cycle_us: 400", "  cycle_us: fast", r"bus\.cycle_us: .*integer.*'fast'", 4),
    ("  cycle_us: 400", "  cycle_us: 50", r"bus: dc\.sync0_shift_us \(55\.0\) must be less", None),
    ("mode: ref_follows_master", "mode: sideways", r"bus\.dc\.mode: .*sideways", 5),
    ("- name: leg_b", "- name: leg_a", r"slaves\[1\]\.name: duplicate slave name.*'leg_a'", 17),
    ("    position: 1", "    position: 0", r"slaves\[1\]\.position: duplicate position", 18),
    ("- name: leg_b", "- name: Leg-B", r"slaves\[1\]\.name: String should match pattern", 17),
    (
        "    device: LaelapsII_Leg",
        "    device: NoSuchLeg",
        r"slaves\[0\]\.device: no such ESI device"
        r" \(known: Coupler, GenericIO, Junction, LaelapsII_Leg, ServoDrive1, ServoDrive2\)"
        r".*NoSuchLeg",
        12,
    ),
    (
        '    product_code: "0x00A986FD"',
        "    product_code: 0x1234",
        r"slaves\[0\]\.product_code: does not match ESI device LaelapsII_Leg",
        11,
    ),
    (
        "    product_code: 0x00A986FD",
        "    product_code: 0x1234",
        r"slaves\[1\]\.product_code: no ESI device with vendor 0x00000a12",
        20,
    ),
    (
        '    product_code: "0x00A986FD"',
        '    product_code: "0xZZ"',
        r"slaves\[0\]\.product_code: .*not an integer",
        11,
    ),
    (
        "State_Machine: 0,",
        "State_Machin: 0,",
        r"slaves\[0\]\.safe_outputs\.State_Machin: no process variable 'State_Machin'",
        13,
    ),
    (
        "State_Machine: 0,",
        "State_Machine: 2,",
        r"slaves\[0\]\.safe_outputs\.State_Machine: .*bool needs true/false or 0/1.*got 2",
        13,
    ),
    (
        "Blue_LED: true",
        "Transition_time: 200",
        r"safe_outputs\.Transition_time: .*200 is out of range for int8 \[-128, 127\]",
        13,
    ),
    ("Blue_LED: true", "hip_angle: 0", r"safe_outputs\.hip_angle: is an input variable", 13),
    (
        "position: hip_angle,",
        "position: hip_angel,",
        r"slaves\[0\]\.joints\[0\]\.position: no process variable 'hip_angel'",
        15,
    ),
    (
        "{name: a_hip,",
        "{name: a_hip, scale: 2,",
        r"slaves\[0\]\.joints\[0\]\.scale: unknown key",
        15,
    ),
    (
        'rx: ["0x1600"]',
        "rx: [0x1700]",
        r"slaves\[2\]\.pdo_assign\.rx\[0\]: GenericIO has no RXPDO.*0x1700",
        24,
    ),
    ("tx: [0x1A00, 0x1A01]", "tx: [0x1600]", r"pdo_assign\.tx\[0\]: GenericIO has no TXPDO", 24),
    (
        "value: -5}",
        "value: 40000}",
        r"slaves\[2\]\.sdo_init\[0\]\.value: 40000 is out of range for int16",
        25,
    ),
    (
        "index: 0x7010",
        "index: 0x1018",
        r"sdo_init\[0\]\.index: object 0x1018:01 \(Vendor ID\) is read-only",
        25,
    ),
    (
        "index: 0x7010",
        "index: 0x2000",
        r"sdo_init\[0\]\.index: object 0x2000:01 is not in the GenericIO dictionary",
        25,
    ),
    (
        "subindex: 1, value",
        "subindex: 1, type: float128, value",
        r"sdo_init\[0\]\.type: unknown data type",
        25,
    ),
    ("esi: [DEVICES]", "esi: [DEVICES/nope.xml]", r"esi\[0\]: ESI file or directory not found", 6),
    ("reference: 0,", "reference: 9,", r"bus\.dc\.reference: no slave at this position.*got 9", 5),
    (
        "dc: {enabled: true,",
        "dc: {enabled: false,",
        r"bus\.dc\.enabled: slave leg_a \(LaelapsII_Leg\) requires distributed clocks",
        5,
    ),
    (
        "    position: 1\n",
        "    position: 1\n    alias: 3\n",
        r"slaves\[1\]: give either position or alias, not both",
        17,
    ),
    (
        "    position: 1\n",
        "",
        r"slaves\[1\]: give position \(or alias\) for every slave, or for none",
        17,
    ),
    (
        "  - name: leg_b\n    position: 1\n    vendor_id: 0x00000A12\n",
        "  - name: leg_b\n    position: 1\n",
        r"slaves\[1\]: give device, or vendor_id and product_code",
        17,
    ),
    ("  name: test_bus\n", "  name: test_bus\n  name: again\n", r"bus\.name: duplicate key", 3),
    ("bus:\n", "bus: [\n", r"invalid YAML", None),
]


@pytest.mark.parametrize(("old", "new", "pattern", "line"), BAD)
def test_bad_config_names_file_line_key_and_value(
    tmp_path: Path, old: str, new: str, pattern: str, line: int | None
) -> None:
    assert old in GOOD, old
    path = write(tmp_path, GOOD.replace(old, new, 1))
    with pytest.raises(ConfigError) as info:
        load_bus_config(path)
    msg = str(info.value)
    assert msg.startswith(str(path)), msg
    assert re.search(pattern, msg), msg
    if line is not None:
        assert msg.startswith(f"{path}:{line}:"), msg
        assert info.value.line == line  # the place as data, too
    assert info.value.file == str(path)
    assert info.value.field is not None and info.value.field in msg


def test_missing_file_and_empty_file(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match=r"nope\.yaml: bus configuration file not found"):
        load_bus_config(tmp_path / "nope.yaml")
    empty = tmp_path / "empty.yaml"
    empty.write_text("")
    with pytest.raises(ConfigError, match="is a mapping"):
        load_bus_config(empty)
    no_slaves = tmp_path / "ns.yaml"
    no_slaves.write_text("bus: {cycle_us: 400}\nslaves: []\n")
    with pytest.raises(ConfigError, match=r"ns\.yaml:2: slaves: List should have at least 1"):
        load_bus_config(no_slaves)


def test_link_and_busy_poll(tmp_path: Path) -> None:
    path = write(tmp_path, GOOD)
    cfg = load_bus_config(path)
    assert (cfg.bus.link, cfg.bus.busy_poll_us) == ("packet", 0)
    assert load_bus_config(path, link="xdp").bus.link == "xdp"
    with pytest.raises(ConfigError, match=r"link must be packet, xdp or auto, got 'dpdk'"):
        load_bus_config(path, link="dpdk")
    bad = write(tmp_path, GOOD.replace("  name: test_bus\n", "  name: test_bus\n  link: dpdk\n", 1))
    with pytest.raises(ConfigError, match=r":3: bus\.link: .*'packet', 'xdp' or 'auto'"):
        load_bus_config(bad)
    bad = write(
        tmp_path, GOOD.replace("  name: test_bus\n", "  name: test_bus\n  busy_poll_us: -1\n", 1)
    )
    with pytest.raises(ConfigError, match=r"bus\.busy_poll_us: .*greater than or equal to 0"):
        load_bus_config(bad)


def test_interface_override_is_checked(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match=r"--interface: an interface name has 1\.\.15 characters"):
        load_bus_config(write(tmp_path, GOOD), interface="x" * 16)


def test_esi_path_is_relative_to_the_yaml(tmp_path: Path) -> None:
    sub = tmp_path / "cfg"
    sub.mkdir()
    (tmp_path / "esi").mkdir()
    (tmp_path / "esi" / "leg.xml").write_text((DEVICES / "laelaps_ii_leg.xml").read_text())
    text = textwrap.dedent(
        """\
        esi: ../esi
        bus: {dc: {enabled: true}}
        slaves:
          - {name: leg, device: LaelapsII_Leg}
        """
    )
    (sub / "bus.yaml").write_text(text)
    cfg = load_bus_config(sub / "bus.yaml")
    assert cfg.slaves[0].esi.source.endswith("leg.xml")


GROUPS = "groups:\n  - {name: io_group, cycle_us: 2000, slaves: [io], watchdog_ms: 20}\n"


def test_groups_run_at_a_multiple_of_the_bus_cycle(tmp_path: Path) -> None:
    cfg = load_bus_config(write(tmp_path, GOOD + GROUPS))
    assert cfg.group_cycles() == [("default", 1), ("io_group", 5)]
    group = cfg.group_of("io")
    assert group is not None and group.name == "io_group" and group.lrw
    assert group.watchdog_ms == 20
    assert cfg.group_of("leg_a") is None


@pytest.mark.parametrize(
    ("groups", "pattern"),
    [
        (
            "groups:\n  - {name: g, cycle_us: 1000, slaves: [io]}\n",
            r"groups\[0\]\.cycle_us.*group g: cycle_us must be a whole multiple of "
            r"bus\.cycle_us \(400\).*1000",
        ),
        (
            "groups:\n  - {name: g, cycle_us: 800, slaves: [io]}\n"
            "  - {name: h, cycle_us: 800, slaves: [leg_b, io]}\n",
            r"groups\[1\]\.slaves\[1\].*slave io is in two groups \(g and h\)",
        ),
        (
            "groups:\n  - {name: g, cycle_us: 800, slaves: []}\n",
            r"groups\[0\]\.slaves.*group g has no slaves",
        ),
        (
            "groups:\n  - {name: g, cycle_us: 800, slaves: [nope]}\n",
            r"groups\[0\]\.slaves\[0\].*group g: no slave named 'nope'",
        ),
        (
            "groups:\n  - {name: default, cycle_us: 800, slaves: [io]}\n",
            r"groups\[0\]\.name.*'default' is the group of slaves in no group",
        ),
        (
            "groups:\n  - {name: g, cycle_us: 800, slaves: [io]}\n"
            "  - {name: g, cycle_us: 1200, slaves: [leg_b]}\n",
            r"groups\[1\]\.name.*'g' is used twice",
        ),
    ],
)
def test_bad_groups_are_named(tmp_path: Path, groups: str, pattern: str) -> None:
    with pytest.raises(ConfigError, match=pattern):
        load_bus_config(write(tmp_path, GOOD + groups))


def test_lrw_false_on_a_slave_and_on_the_simulated_esc(tmp_path: Path) -> None:
    text = GOOD.replace("    device: GenericIO\n", "    device: GenericIO\n    lrw: false\n"
                        "    sim: {lrw: false}\n")  # fmt: skip
    cfg = load_bus_config(write(tmp_path, text))
    io = cfg.slave("io")
    assert io.lrw is False and io.sim.lrw is False
