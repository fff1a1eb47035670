"""The devices users own: every real vendor ESI of ``shared/esi-vendor`` (Beckhoff EK/EL/EP
terminals, Elmo, Inovance, Synapticon, STMBL, EasyCAT/EtherBerry, SOES samples, SMC, NI,
Pollen) loads, every device of every file runs as a virtual slave and reaches OP under our
master with the expected working counter and process data flowing, and pysoem and ethercrab
bring a representative bus of each file to OP. The files are read where they are (never copied
into the project); without the folder these tests skip, saying so.

Buses of many slaves keep CI short: the two big Beckhoff files alone, the other Beckhoff files
together, the other vendors together (``ether_ros.tools.vendor_corpus``); the simulator runs in
its own process and network namespace on the far end of a veth pair.
"""

from __future__ import annotations

import json
import re
import shutil
import subprocess
from pathlib import Path

import pytest

from ether_ros.config.bus import load_bus_config
from ether_ros.config.esi import load_esi, load_esi_file
from ether_ros.config.from_esi import bus_yaml_for_devices
from ether_ros.errors import ConfigError
from ether_ros.master import Bus
from ether_ros.sim.proof import OP, SimProcess, SoemBus
from ether_ros.sim.spec import bus_order
from ether_ros.testing.netns import VethPair
from ether_ros.testing.wait import wait_for
from ether_ros.tools.vendor_corpus import (
    BUS_GROUPS,
    OTHER_VENDORS,
    SIM_READY_S,
    bus_devices,
    bus_groups,
    echo_checks,
    no_vendor_dir_reason,
    own_assignment_sizes,
    representative_buses,
    run_ethercrab,
    sync0_latched_one_buffer_inputs,
    vendor_dir,
    vendor_files,
)

VENDOR = vendor_dir()
needs_corpus = pytest.mark.skipif(
    VENDOR is None,
    reason=f"{no_vendor_dir_reason()}: the real-device tests need it",
)
GROUPS = [name for name, _files in BUS_GROUPS] + [OTHER_VENDORS]
REPO = Path(__file__).resolve().parents[2]
PROBE_DIR = REPO / "tests" / "ethercrab_probe"


def _corpus() -> Path:
    assert VENDOR is not None
    return VENDOR


def _buses() -> list[tuple[str, list[object]]]:
    return representative_buses(VENDOR) if VENDOR is not None else []


# --------------------------------------------------------------------------------------------
# Loading


@needs_corpus
def test_every_vendor_file_loads_with_hundreds_of_devices() -> None:
    files = vendor_files(_corpus())
    assert len(files) >= 23, files
    total = 0
    for f in files:
        esi = load_esi_file(f)
        assert esi.devices, f"{f}: {esi.warnings}"
        assert esi.skipped_devices == (), esi.skipped_devices
        for w in esi.warnings:
            # A warning is one line naming file, line and element: the ESI file, or a
            # dictionary file in its folder that one of its devices names.
            named = Path(w.file)
            assert named == f or f.parent in named.parents, w
            assert re.match(rf"^{re.escape(w.file)}:\d+: <[^>]+>: ", str(w)), w
            assert "\n" not in str(w)
        total += len(esi.devices)
    assert total >= 400, total


@needs_corpus
def test_a_vendor_folder_s_dictionary_files_are_read_for_the_devices_that_name_them() -> None:
    """Beckhoff's AX5000 ESI names each device's IDN dictionary in a file of its own
    (``<DictionaryFile>Beckhoff AX5xxx\\Beckhoff AX5101-xxxx-0210 Dict.xml``, a Windows
    path; root ``<EtherCATDict>``). The corpus holds two of the 155: those two devices get
    their dictionary, every other device one warning naming the missing file, and the
    dictionary files are no ESI files of their own."""
    root = _corpus()
    files = vendor_files(root)
    assert not [f for f in files if f.name.endswith(" Dict.xml")], files
    (ax,) = [f for f in files if f.name == "Beckhoff AX5xxx.xml"]
    esi = load_esi_file(ax)
    present = {p.name for p in (ax.parent / "Beckhoff AX5xxx").glob("*Dict.xml")}
    assert len(present) == 2, present
    by_type = {d.type_name: d for d in esi.devices}
    drive = by_type["AX5101-0000-0210"]
    assert drive.mailbox is not None and drive.mailbox.soe and not drive.mailbox.coe
    # Sercos drive: the dictionary is its IDNs (S-0-0001 TNcyc, P-0-0010 = 0x800A ...),
    # kept apart from the CoE dictionary it does not have.
    idns = {o.index: o for o in drive.idns}
    assert drive.objects == ()
    assert len(idns) > 500, len(idns)
    assert "TNcyc" in idns[1].name
    assert 0x800A in idns  # P-0-0010, the init command's feature flags
    missing = [w for w in esi.warnings if "DictionaryFile not found" in w.message]
    named = [d for d in esi.devices if d.idns]
    assert len(named) == 2, [d.type_name for d in named]
    assert len(missing) == len(esi.devices) - len(named), len(missing)
    assert all(Path(w.file) == ax and " Dict.xml" in w.message for w in missing)
    with pytest.raises(ConfigError, match=r"a dictionary file, not an ESI file"):
        load_esi_file(ax.parent / "Beckhoff AX5xxx" / sorted(present)[0])


@needs_corpus
def test_the_not_well_formed_file_loads_with_a_warning_naming_line_and_column() -> None:
    (f,) = [f for f in vendor_files(_corpus()) if f.name == "DS402_PDOs_EasyCatProject.xml"]
    esi = load_esi_file(f)
    assert len(esi.devices) == 1
    assert [str(w) for w in esi.warnings] == [
        f"{f}:36: <xml>: not well-formed XML at column 15 (EntityRef: expecting ';'): an"
        " unescaped '&', read as '&amp;'"
    ]
    assert esi.devices[0].vendor_name == "AB&T"


@needs_corpus
def test_vendor_constructs_that_used_to_reject_whole_files() -> None:
    root = _corpus()

    def device(file: str, type_name: str) -> object:
        (path,) = [f for f in vendor_files(root) if f.name == file]
        return max(
            (d for d in load_esi(path) if d.type_name == type_name), key=lambda d: d.revision
        )

    # Passive terminals have no ProductCode: loaded, marked passive (not on the bus).
    end_cap = device("Beckhoff EL9xxx.xml", "EL9011")
    assert end_cap.passive  # type: ignore[attr-defined]
    # EL2252: a Virtual RxPDO reuses an index; its SMs map DC registers (0x0981, 0x0990).
    el2252 = device("Beckhoff EL2xxx.xml", "EL2252")
    assert [sm.virtual for sm in el2252.sync_managers][:2] == [True, True]  # type: ignore[attr-defined]
    # SV660: a bit pattern as the default of a DINT.
    # SMC EX250: UINT8 entries, and an SM the vendor calls "Outputs" whose ControlByte reads.
    ex250 = device("SMC EX250-SEN1-X156.xml", "EX250-SEN1-X156")
    assert [sm.role for sm in ex250.sync_managers] == ["Outputs", "Inputs"]  # type: ignore[attr-defined]
    # Orbita2d: SMs named by the vendor, direction from the ControlByte.
    orbita = device("Orbita2d.xml", "Orbita2d")
    assert [sm.role for sm in orbita.sync_managers] == [  # type: ignore[attr-defined]
        "MBoxOut", "MBoxIn", "Outputs", "Inputs"
    ]  # fmt: skip
    # IS620N: an array's elements take their base type's size (0x1C12:01 is 16 bits).
    is620n = device("IS620N_v2.6.7.xml", "IS620N")
    entry = is620n.od_entry(0x1C12, 1)  # type: ignore[attr-defined]
    assert entry is not None and entry.bit_length == 16
    assert [c.transitions for c in is620n.init_cmds] == [("PS",)]  # type: ignore[attr-defined]


# --------------------------------------------------------------------------------------------
# Every device under our master


@needs_corpus
@pytest.mark.netns
@pytest.mark.parametrize("group", GROUPS)
def test_every_device_reaches_op_under_our_master(group: str, tmp_path: Path) -> None:
    """Every device of the group's files on one bus: all reach OP, every cyclic frame comes
    back with its expected working counter (each slave's FMMUs answer), and an output of every
    loopback slave comes back in its paired input."""
    files = bus_groups(_corpus())[group]
    devices = bus_devices(files)
    yml = bus_yaml_for_devices(devices, tmp_path / f"{group}.yaml")
    with (
        VethPair.create(netns=True) as veth,
        SimProcess(yml, veth.slave, veth.netns, ready_timeout=SIM_READY_S),
    ):
        cfg = load_bus_config(yml, interface=veth.master)
        with Bus.open(cfg) as bus:
            bus.start()
            states = bus.states()
            assert [s.name for s in states if s.state != "OP"] == []
            assert bus.layout is not None
            expected = [f.expected_wkc for f in bus.layout.frames]
            assert sum(expected) > len(devices)

            def every_frame_has_its_working_counter() -> bool:
                frames = bus.stats()["frames"]
                return [f["last_wkc"] for f in frames] == expected

            wait_for("every frame's expected working counter", every_frame_has_its_working_counter)
            # Input-only terminals (the EL1 bus) have no output to echo: their working
            # counter above shows their inputs are read.
            checks = echo_checks(cfg)
            assert checks or group == "beckhoff_el1"
            commands: dict[str | int, dict[str, object]] = {}
            for c in checks:
                commands.setdefault(c.slave, {})[c.output.key] = c.value

            def echoed() -> list[str]:
                # Commanded as an application does, every time: the bus's command watchdog
                # (100 ms) puts the safe outputs back when the commands stop, and reading a
                # big bus's inputs one by one can take longer than that on a loaded host.
                bus.write_slaves(commands)
                return [
                    f"{c.slave}.{c.input.key}"
                    for c in checks
                    if bus.read(c.slave, c.input.key) != c.value
                ]

            wait_for("every loopback slave's echo", lambda: not echoed(), timeout=30)


# --------------------------------------------------------------------------------------------
# Representative buses under pysoem and ethercrab


@needs_corpus
@pytest.mark.netns
@pytest.mark.parametrize("index", range(5))
def test_pysoem_brings_a_representative_bus_of_each_file_to_op(index: int, tmp_path: Path) -> None:
    buses = _buses()
    if index >= len(buses):
        pytest.skip(f"the corpus makes {len(buses)} representative buses")
    name, devices = buses[index]
    yml = bus_yaml_for_devices(devices, tmp_path / f"{name}.yaml")  # type: ignore[arg-type]
    cfg = load_bus_config(yml)
    with (
        VethPair.create(netns=True, master_netns=True) as veth,
        SimProcess(yml, veth.slave, veth.netns, ready_timeout=SIM_READY_S),
    ):
        soem = SoemBus(cfg, veth.master, netns=veth.master_netns)
        try:
            assert soem.scan() == len(devices)
            soem.set_watchdog(2000)
            soem.configure()
            reached = soem.request_op(timeout_s=15)
            states = soem.states()
            assert reached, [
                (s.name, st, f"{code:#06x}")
                for s, (st, code) in zip(bus_order(cfg), states, strict=True)
                if st != OP
            ]
            soem.run(0.5)
            # Each slave's FMMUs answer the LRW: +2 when it has outputs, +1 with inputs (ESC
            # datasheet, working counter). SOEM's own expected_wkc counts its IO map's
            # segments, not slaves, so it is not used. A slave with a one-buffer input SM
            # (EL1252) misses a read when two frames fall between its SYNC0 latches, as on
            # hardware: the expected count is the highest one seen.
            slaves = soem.slaves
            expected = sum((2 if len(s.output) else 0) + (1 if len(s.input) else 0) for s in slaves)
            seen = soem.stats.wkc_seen
            assert max(seen) == expected, seen
            for s, c in zip(slaves, bus_order(cfg), strict=True):
                layout = own_assignment_sizes(c)
                assert (len(s.output), len(s.input)) == (
                    layout.output_bytes,
                    layout.input_bytes,
                ), c.name
        finally:
            soem.close()


@pytest.fixture(scope="module")
def probe() -> Path:
    """The ethercrab probe binary, built (release) from its pinned lock file."""
    cargo = shutil.which("cargo") or str(Path.home() / ".cargo" / "bin" / "cargo")
    if not Path(cargo).exists():
        pytest.fail("cargo is needed to build the ethercrab probe (tests/ethercrab_probe)")
    build = subprocess.run(
        [cargo, "build", "--release", "--locked", "-q"],
        cwd=PROBE_DIR,
        capture_output=True,
        text=True,
        check=False,
    )
    assert build.returncode == 0, build.stderr[-3000:]
    return PROBE_DIR / "target" / "release" / "ethercrab-probe"


@needs_corpus
@pytest.mark.netns
@pytest.mark.parametrize("index", range(5))
def test_ethercrab_brings_a_representative_bus_of_each_file_to_op(
    index: int, tmp_path: Path, probe: Path
) -> None:
    buses = _buses()
    if index >= len(buses):
        pytest.skip(f"the corpus makes {len(buses)} representative buses")
    name, devices = buses[index]
    # Not the devices whose inputs are a one-buffer SM filled on SYNC0 (AX5000): the probe
    # sends on its own timer, out of phase with SYNC0, and misses their inputs now and then
    # as it would on the real drives; pysoem and our master run them on the same bus.
    devices = [d for d in devices if not sync0_latched_one_buffer_inputs(d)]  # type: ignore[arg-type]
    yml = bus_yaml_for_devices(devices, tmp_path / f"{name}.yaml")  # type: ignore[arg-type]
    cfg = load_bus_config(yml)
    with (
        VethPair.create(netns=True, master_netns=True) as veth,
        SimProcess(yml, veth.slave, veth.netns, ready_timeout=SIM_READY_S),
    ):
        result = run_ethercrab(probe, veth.master, cfg, cycles=1000, netns=veth.master_netns)
    summary = {k: result.get(k) for k in ("exit", "error", "op", "cycles", "wkc_errors",
                                          "tx_rx_errors", "wkc_first", "wkc_wrong")}  # fmt: skip
    assert result["exit"] == 0 and result["error"] is None, summary
    assert result["op"] and result["wkc_errors"] == 0, summary
    for seen, s in zip(result["slaves"], bus_order(cfg), strict=True):
        assert (seen["vendor_id"], seen["product_code"]) == (s.esi.vendor_id, s.esi.product_code)
    for out, inp, s in zip(result["outputs"], result["inputs"], bus_order(cfg), strict=True):
        layout = own_assignment_sizes(s)
        assert (len(out) // 2, len(inp) // 2) == (layout.output_bytes, layout.input_bytes), s.name


# --------------------------------------------------------------------------------------------
# A mixed bus of real devices under the three masters, its drive moving


# No command watchdog: a timed move is one command, and this test feeds nothing while it runs.
MIXED = """bus: {{name: mixed_real, cycle_us: 1000, watchdog_ms: 0, dc: {{enabled: true}}}}
esi: {esi}
slaves:
  - {{name: coupler, device: EK1100}}
  - {{name: inputs, device: EL1008}}
  - {{name: outputs, device: EL2008}}
  - {{name: analog, device: EL3602}}
  - name: drive
    device: IS620N
    axes:
      - {{name: joint, mode: csp, position_scale: 0.0001, velocity_scale: 0.0001,
         torque_scale: 0.001}}
"""
MIXED_FILES = (
    "Beckhoff EK11xx.xml",
    "Beckhoff EL1xxx.xml",
    "Beckhoff EL2xxx.xml",
    "Beckhoff EL3xxx.xml",
    "IS620N_v2.6.7.xml",
)


def _mixed_config(tmp_path: Path) -> Path:
    files = [str(f) for f in vendor_files(_corpus()) if f.name in MIXED_FILES]
    assert len(files) == len(MIXED_FILES), files
    yml = tmp_path / "mixed_real.yaml"
    yml.write_text(MIXED.format(esi=json.dumps(files)))
    return yml


@needs_corpus
@pytest.mark.netns
def test_mixed_real_bus_under_our_master_moves_its_drive(tmp_path: Path) -> None:
    """EK1100, EL1008, EL2008, EL3602 and an Inovance IS620N drive (whose 0x6502 is a
    placeholder): OP with every frame's working counter, an output of the EL2008 reaches the
    ESC's digital output register, and the drive follows a move through the Axis API."""
    yml = _mixed_config(tmp_path)
    with (
        VethPair.create(netns=True) as veth,
        SimProcess(yml, veth.slave, veth.netns, ready_timeout=SIM_READY_S) as sim,
    ):
        cfg = load_bus_config(yml, interface=veth.master)
        with Bus.open(cfg) as bus:
            bus.start()
            assert [s.state for s in bus.states()] == ["OP"] * 5
            assert bus.layout is not None
            expected = [f.expected_wkc for f in bus.layout.frames]
            wait_for(
                "every frame's expected working counter",
                lambda: [f["last_wkc"] for f in bus.stats()["frames"]] == expected,
            )
            # EL2008: its SM sits on the ESC's digital outputs (0x0F00).
            bus.write("outputs", "0x7020:01", True)
            el2008 = bus.slave("outputs")

            def digital_outputs() -> int:
                data, wkc = bus.dg.fprd(el2008.station, 0x0F00, 1)
                return data[0] if wkc == 1 else -1

            wait_for("the EL2008's output register", lambda: digital_outputs() & 0x04 == 0x04)
            joint = bus.axis("joint")
            assert joint.spec.modes and "csp" in joint.spec.modes
            joint.enable(timeout=10)
            p0 = joint.position
            joint.follow([(0.0, p0, 0.0), (1.0, p0 + 0.5, 0.0)], start_in=0.05)
            wait_for("the move", lambda: joint.status()["trajectory_done"], timeout=30)
            wait_for("the drive at its target", lambda: abs(joint.position - p0 - 0.5) < 0.01)
            st = joint.status()
            assert st["faults"] == 0 and not st["following_error_exceeded"], st
            # The simulated drive itself moved (its load, in its own units).
            probe = sim.request({"op": "probe", "slave": 4})
            assert abs(probe["axis1_demand_position_rad"]) > 0.0, probe


@needs_corpus
@pytest.mark.netns
def test_mixed_real_bus_under_pysoem(tmp_path: Path) -> None:
    yml = _mixed_config(tmp_path)
    cfg = load_bus_config(yml)
    with (
        VethPair.create(netns=True, master_netns=True) as veth,
        SimProcess(yml, veth.slave, veth.netns, ready_timeout=SIM_READY_S),
    ):
        soem = SoemBus(cfg, veth.master, netns=veth.master_netns)
        try:
            assert soem.scan() == 5
            soem.set_watchdog(2000)
            soem.configure()
            assert soem.request_op(timeout_s=15), soem.states()
            soem.run(0.3)
            expected = sum(
                (2 if len(s.output) else 0) + (1 if len(s.input) else 0) for s in soem.slaves
            )
            assert max(soem.stats.wkc_seen) == expected, soem.stats
        finally:
            soem.close()


@needs_corpus
@pytest.mark.netns
def test_mixed_real_bus_under_ethercrab(tmp_path: Path, probe: Path) -> None:
    yml = _mixed_config(tmp_path)
    cfg = load_bus_config(yml)
    with (
        VethPair.create(netns=True, master_netns=True) as veth,
        SimProcess(yml, veth.slave, veth.netns, ready_timeout=SIM_READY_S),
    ):
        result = run_ethercrab(probe, veth.master, cfg, cycles=1000, netns=veth.master_netns)
    summary = {k: result.get(k) for k in ("exit", "error", "op", "cycles", "wkc_errors")}
    assert result["exit"] == 0 and result["op"] and result["wkc_errors"] == 0, summary
