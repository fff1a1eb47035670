"""Devices as vendors describe them, configured as TwinCAT and IgH do: the ESI default PDO
assignment written where the slave differs, CoE init commands in their transitions, ETG.2001
modules in slots, a bus without process data, CiA 402 modes from the dictionary when 0x6502 is
a placeholder, and the communication objects the simulator builds when a dictionary lacks
them. Buses run in process on the simulator (``Bus.open(cfg, link=net)``)."""

# ruff: noqa: E501  (ESI lines read best whole)
from __future__ import annotations

from pathlib import Path

import pytest

from ether_ros.config import load_bus_config
from ether_ros.config.cia402 import offered_modes
from ether_ros.config.esi import default_modules, load_esi, place_modules
from ether_ros.errors import ConfigError
from ether_ros.master import Bus
from ether_ros.sim.network import build_network
from ether_ros.sim.spec import communication_objects, device_spec
from ether_ros.testing.wait import wait_for

HEAD = '<?xml version="1.0"?>\n<EtherCATInfo><Vendor><Id>#x99</Id><Name>V</Name></Vendor><Descriptions><Devices>\n'
TAIL = "</Devices>{modules}</Descriptions></EtherCATInfo>\n"
MAILBOX_SMS = (
    '<Sm StartAddress="#x1000" DefaultSize="128" ControlByte="#x26" Enable="1">MBoxOut</Sm>'
    '<Sm StartAddress="#x1080" DefaultSize="128" ControlByte="#x22" Enable="1">MBoxIn</Sm>'
    '<Sm StartAddress="#x1100" ControlByte="#x64" Enable="1">Outputs</Sm>'
    '<Sm StartAddress="#x1180" ControlByte="#x20" Enable="1">Inputs</Sm>'
)
DRIVE = (
    '<Device Physics="YY"><Type ProductCode="#x402" RevisionNo="1">Drive</Type><Name>Drive</Name>'
    "<Profile><ProfileNo>402</ProfileNo><Dictionary><DataTypes>"
    "<DataType><Name>DT1C12ARR</Name><BaseType>UINT</BaseType><BitSize>32</BitSize><ArrayInfo><LBound>1</LBound><Elements>2</Elements></ArrayInfo></DataType>"
    "<DataType><Name>DT1C12</Name><BitSize>48</BitSize><SubItem><SubIdx>0</SubIdx><Name>SubIndex 000</Name><Type>USINT</Type><BitSize>8</BitSize><Flags><Access>rw</Access></Flags></SubItem>"
    "<SubItem><Name>Elements</Name><Type>DT1C12ARR</Type><BitSize>32</BitSize><Flags><Access>rw</Access></Flags></SubItem></DataType>"
    "</DataTypes><Objects>"
    # The stored assignment is not the ESI's default (0x1601 instead of 0x1600).
    "<Object><Index>#x1C12</Index><Name>RxPDO assign</Name><Type>DT1C12</Type><BitSize>48</BitSize><Info>"
    "<SubItem><Name>SubIndex 000</Name><Info><DefaultData>01</DefaultData></Info></SubItem>"
    "<SubItem><Name>SubIndex 001</Name><Info><DefaultData>0116</DefaultData></Info></SubItem></Info></Object>"
    "<Object><Index>#x6040</Index><Name>Controlword</Name><Type>UINT</Type><BitSize>16</BitSize><Flags><Access>rw</Access><PdoMapping>R</PdoMapping></Flags></Object>"
    "<Object><Index>#x6041</Index><Name>Statusword</Name><Type>UINT</Type><BitSize>16</BitSize><Flags><Access>ro</Access><PdoMapping>T</PdoMapping></Flags></Object>"
    "<Object><Index>#x6060</Index><Name>Modes of operation</Name><Type>SINT</Type><BitSize>8</BitSize><Flags><Access>rw</Access></Flags></Object>"
    "<Object><Index>#x607A</Index><Name>Target position</Name><Type>DINT</Type><BitSize>32</BitSize><Flags><Access>rw</Access><PdoMapping>R</PdoMapping></Flags></Object>"
    "<Object><Index>#x6064</Index><Name>Position actual</Name><Type>DINT</Type><BitSize>32</BitSize><Flags><Access>ro</Access><PdoMapping>T</PdoMapping></Flags></Object>"
    # A placeholder: the drive fills in its modes at run time.
    "<Object><Index>#x6502</Index><Name>Supported drive modes</Name><Type>UDINT</Type><BitSize>32</BitSize><Info><DefaultValue>0</DefaultValue></Info><Flags><Access>ro</Access></Flags></Object>"
    "<Object><Index>#x2000</Index><Name>Setting</Name><Type>USINT</Type><BitSize>8</BitSize><Flags><Access>rw</Access></Flags></Object>"
    "</Objects></Dictionary></Profile>"
    + MAILBOX_SMS
    + '<RxPdo Fixed="1" Sm="2"><Index>#x1600</Index><Name>Out</Name>'
    "<Entry><Index>#x6040</Index><SubIndex>0</SubIndex><BitLen>16</BitLen><Name>Controlword</Name><DataType>UINT</DataType></Entry>"
    "<Entry><Index>#x607A</Index><SubIndex>0</SubIndex><BitLen>32</BitLen><Name>Target position</Name><DataType>DINT</DataType></Entry></RxPdo>"
    '<RxPdo Fixed="1"><Index>#x1601</Index><Name>Out short</Name>'
    "<Entry><Index>#x6040</Index><SubIndex>0</SubIndex><BitLen>16</BitLen><Name>Controlword</Name><DataType>UINT</DataType></Entry></RxPdo>"
    '<TxPdo Fixed="1" Sm="3"><Index>#x1A00</Index><Name>In</Name>'
    "<Entry><Index>#x6041</Index><SubIndex>0</SubIndex><BitLen>16</BitLen><Name>Statusword</Name><DataType>UINT</DataType></Entry>"
    "<Entry><Index>#x6064</Index><SubIndex>0</SubIndex><BitLen>32</BitLen><Name>Position actual</Name><DataType>DINT</DataType></Entry></TxPdo>"
    '<Mailbox><CoE SdoInfo="1" PdoAssign="1" PdoConfig="0">'
    "<InitCmd><Transition>PS</Transition><Index>#x2000</Index><SubIndex>0</SubIndex><Data>42</Data><Comment>setting</Comment></InitCmd>"
    "<InitCmd><Transition>IP</Transition><Transition>PS</Transition><Index>#x6060</Index><SubIndex>0</SubIndex><Data>08</Data></InitCmd>"
    "</CoE></Mailbox></Device>\n"
)
COUPLER = '<Device Physics="YY"><Type ProductCode="#x1100" RevisionNo="1">Coupler</Type><Name>Coupler</Name></Device>\n'
MODULAR = (
    '<Device Physics="YY"><Type ProductCode="#x5001" RevisionNo="1">Modular</Type><Name>Modular</Name>'
    + MAILBOX_SMS
    + '<Mailbox><CoE SdoInfo="1" PdoAssign="1" PdoConfig="1"/></Mailbox>'
    '<Slots SlotPdoIncrement="16" SlotIndexIncrement="#x800">'
    '<Slot MinInstances="1" MaxInstances="1"><Name>Axis 1</Name><ModuleIdent Default="1">#x100</ModuleIdent><ModuleIdent>#x200</ModuleIdent></Slot>'
    '<Slot MinInstances="0" MaxInstances="1"><Name>Axis 2</Name><ModuleIdent Default="1">#x100</ModuleIdent><ModuleIdent>#x200</ModuleIdent></Slot>'
    "</Slots></Device>\n"
)
MODULES = (
    "<Modules>"
    '<Module><Type ModuleIdent="#x100">Position</Type><Name>Position</Name>'
    '<RxPdo Fixed="1" Sm="2"><Index DependOnSlot="true">#x1600</Index><Name>Pos out</Name>'
    '<Entry><Index DependOnSlot="true">#x607A</Index><SubIndex>0</SubIndex><BitLen>32</BitLen><Name>Target</Name><DataType>DINT</DataType></Entry></RxPdo>'
    '<TxPdo Fixed="1" Sm="3"><Index DependOnSlot="true">#x1A00</Index><Name>Pos in</Name>'
    '<Entry><Index DependOnSlot="true">#x6064</Index><SubIndex>0</SubIndex><BitLen>32</BitLen><Name>Actual</Name><DataType>DINT</DataType></Entry></TxPdo>'
    "</Module>"
    '<Module><Type ModuleIdent="#x200">Velocity</Type><Name>Velocity</Name>'
    '<RxPdo Fixed="1" Sm="2"><Index DependOnSlot="true">#x1600</Index><Name>Vel out</Name>'
    '<Entry><Index DependOnSlot="true">#x60FF</Index><SubIndex>0</SubIndex><BitLen>32</BitLen><Name>Target vel</Name><DataType>DINT</DataType></Entry></RxPdo>'
    "</Module></Modules>"
)


def _esi(tmp_path: Path, *devices: str, modules: str = "") -> Path:
    p = tmp_path / "devices.xml"
    p.write_text(HEAD + "".join(devices) + TAIL.format(modules=modules))
    return p


def _config(tmp_path: Path, esi: Path, slaves: str) -> Path:
    p = tmp_path / "bus.yaml"
    p.write_text(
        f"bus: {{name: t, cycle_us: 1000, dc: {{enabled: false}}}}\nesi: [{esi}]\nslaves:\n{slaves}"
    )
    return p


def test_supported_modes_from_the_dictionary_when_6502_is_a_placeholder(tmp_path: Path) -> None:
    (drive,) = load_esi(_esi(tmp_path, DRIVE))
    entry = drive.od_entry(0x6502, 0)
    assert entry is not None and entry.default == bytes(4)
    # 0x607A is there, 0x60FF, 0x6071 and 0x6098 are not: the position modes.
    assert offered_modes(drive, 0) == ("pp", "csp")


@pytest.mark.netns  # the bus runs SCHED_FIFO with locked memory (default realtime)
def test_the_master_writes_the_esi_assignment_and_runs_the_init_commands(tmp_path: Path) -> None:
    """The drive stores 0x1601 in 0x1C12, the ESI assigns 0x1600 by default: the master reads
    the slave's assignment and writes the ESI's (TwinCAT and IgH do), so SAFEOP is accepted; the
    ESI's init commands of INIT->PREOP and PREOP->SAFEOP are sent in order."""
    cfg = load_bus_config(
        _config(
            tmp_path,
            _esi(tmp_path, DRIVE),
            "  - {name: drive, device: Drive, sim: {device: none}}\n",
        )
    )
    net = build_network(cfg)
    assert net.od_read(0, 0x1C12, 1) == (0x1601).to_bytes(2, "little")
    with Bus.open(cfg, link=net) as bus:
        bus.start()
        assert [s.state for s in bus.states()] == ["OP"]
        assert net.od_read(0, 0x1C12, 0) == b"\x01"
        assert net.od_read(0, 0x1C12, 1) == (0x1600).to_bytes(2, "little")
        assert net.od_read(0, 0x2000, 0) == b"\x42"
        assert net.od_read(0, 0x6060, 0) == b"\x08"


@pytest.mark.netns  # the bus runs SCHED_FIFO with locked memory (default realtime)
def test_a_bus_without_process_data_reaches_op(tmp_path: Path) -> None:
    cfg = load_bus_config(
        _config(
            tmp_path,
            _esi(tmp_path, COUPLER),
            "  - {name: a, device: Coupler}\n  - {name: b, device: Coupler}\n",
        )
    )
    with Bus.open(cfg, link=build_network(cfg)) as bus:
        bus.start()
        assert [s.state for s in bus.states()] == ["OP", "OP"]
        assert bus.layout is not None
        # One LRD of a byte no slave maps keeps the cyclic frame going (working counter 0).
        ((heartbeat,),) = [f.datagrams for f in bus.layout.frames]
        assert (heartbeat.command, heartbeat.length, heartbeat.expected_wkc) == ("lrd", 1, 0)
        wait_for("heartbeat frames", lambda: bus.stats()["frames"][0]["sent"] > 10)
        assert bus.stats()["frames"][0]["wkc_errors"] == 0


@pytest.mark.netns  # the bus runs SCHED_FIFO with locked memory (default realtime)
def test_modules_go_into_slots_by_default_and_by_config(tmp_path: Path) -> None:
    esi = _esi(tmp_path, MODULAR, modules=MODULES)
    (dev,) = load_esi(esi)
    assert (dev.slot_pdo_increment, dev.slot_index_increment) == (16, 0x800)
    placed = place_modules(dev, default_modules(dev))
    assert [(p.index, [e.index for e in p.entries]) for p in placed.rx_pdos] == [
        (0x1600, [0x607A]), (0x1610, [0x607A + 0x800])
    ]  # fmt: skip
    cfg = load_bus_config(
        _config(tmp_path, esi, "  - {name: m, device: Modular, modules: [Velocity, null]}\n")
    )
    layout = cfg.slaves[0].layout
    assert [v.index for v in layout.outputs] == [0x60FF] and layout.inputs == ()
    with Bus.open(cfg, link=build_network(cfg)) as bus:
        bus.start()
        assert [s.state for s in bus.states()] == ["OP"]
    for modules, message in (
        ("[Torque]", r"modules\[0\]: slot 1 \(Axis 1\) of Modular takes: Position, Velocity"),
        ("[null]", r"modules\[0\]: slot 1 \(Axis 1\) must hold a module"),
        ("[Position, Position, Position]", r"modules: Modular has 2 slots"),
    ):
        with pytest.raises(ConfigError, match=message):
            load_bus_config(
                _config(tmp_path, esi, f"  - {{name: m, device: Modular, modules: {modules}}}\n")
            )


def test_communication_objects_from_the_esi_when_the_dictionary_lacks_them(tmp_path: Path) -> None:
    (dev,) = load_esi(_esi(tmp_path, MODULAR, modules=MODULES))
    dev = place_modules(dev, default_modules(dev))
    rows = {(r[0], r[1]): r for r in communication_objects(dev)}
    # 0x1C00: the SM types (mailbox out, in, outputs, inputs).
    assert [rows[(0x1C00, k)][7][0] for k in range(5)] == [4, 1, 2, 3, 4]
    # 0x1C12/0x1C13: the default assignment; 0x1600 and 0x1610: their mapping.
    assert rows[(0x1C12, 0)][7] == b"\x02"
    assert [int.from_bytes(rows[(0x1C12, k)][7], "little") for k in (1, 2)] == [0x1600, 0x1610]
    assert int.from_bytes(rows[(0x1610, 1)][7], "little") == 0x687A0020
    spec = device_spec(dev, name="m")
    assert {0x1C00, 0x1C12, 0x1C13, 0x1600, 0x1610} <= {o[0] for o in spec.objects}


def test_a_passive_terminal_in_a_config_is_refused_by_name(tmp_path: Path) -> None:
    esi = _esi(
        tmp_path, COUPLER, '<Device Invisible="1"><Type>EndCap</Type><Name>End</Name></Device>\n'
    )
    with pytest.raises(
        ConfigError, match=r"EndCap is a passive terminal: it has no EtherCAT slave controller"
    ):
        load_bus_config(_config(tmp_path, esi, "  - {name: cap, device: EndCap}\n"))


def test_esi_command_lists_devices_pdos_modes_and_what_was_skipped(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from ether_ros.cli.main import main

    broken = DRIVE.replace(
        "<BitLen>32</BitLen><Name>Position actual", "<BitLen>16</BitLen><Name>Position actual", 1
    )
    esi = _esi(
        tmp_path, broken, '<Device Invisible="1"><Type>EndCap</Type><Name>End</Name></Device>\n'
    )
    assert main(["esi", str(esi)]) == 0
    out = capsys.readouterr().out
    assert f"{esi}: 2 device(s), 1 passive, 1 warning(s)" in out
    assert "RxPDO 0x1600 'Out' SM2, 48 bits [default, fixed]" in out
    assert "axis 1 modes: pp, csp" in out
    assert "init command PS 0x2000:00 = 42 (setting)" in out
    assert "passive terminal: no EtherCAT slave controller" in out
    # The TxPDO whose entry does not match its type is skipped, one line naming file and line.
    (warning,) = [line for line in out.splitlines() if line.strip().startswith("warning:")]
    assert f"{esi}:" in warning and "<Entry>: BitLen 16 does not match data type DINT" in warning
    assert main(["esi", str(esi), "--json"]) == 0
    assert '"type": "Drive"' in capsys.readouterr().out
    assert main(["esi", "/dev/zero"]) == 2
    err = capsys.readouterr().err.strip()
    assert err == "ether-ros esi: error: /dev/zero: not a regular file (an ESI must be an XML file)"
