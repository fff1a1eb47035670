"""The FoE store of a simulated slave from the bus config (``sim: {foe: ...}``): what reaches
the slave spec, and the clear errors for a store that cannot be built."""

from __future__ import annotations

from pathlib import Path

import pytest

from ether_ros._native import FoeSpec, SimNetwork
from ether_ros._native.protocol import mailbox, sii_word
from ether_ros.config import load_bus_config
from ether_ros.errors import ConfigError
from ether_ros.sim.spec import network_specs

REPO = Path(__file__).resolve().parents[2]
GENERIC_ESI = REPO / "devices" / "generic_io.xml"

CONFIG = """\
bus: {{name: foe, cycle_us: 1000, dc: {{enabled: false}}}}
esi: [{esi}]
slaves:
  - name: io
    position: 0
    device: GenericIO
    sim: {{foe: {foe}}}
"""


def _esi_with_foe(into: Path) -> Path:
    """devices/generic_io.xml announcing FoE beside CoE."""
    text = GENERIC_ESI.read_text()
    coe_end = text.index("/>", text.index("<CoE ")) + 2
    esi = into / "generic_foe.xml"
    esi.write_text(text[:coe_end] + "<FoE/>" + text[coe_end:])
    return esi


def _config(tmp_path: Path, foe: str, esi: Path | None = None) -> Path:
    yml = tmp_path / "bus.yaml"
    yml.write_text(CONFIG.format(esi=esi or _esi_with_foe(tmp_path), foe=foe))
    return yml


def test_the_store_reaches_the_spec_with_files_by_text_hex_and_path(tmp_path: Path) -> None:
    (tmp_path / "blob.bin").write_bytes(b"\x00\x01\x02")
    foe = (
        "{password: 0x1234, capacity: 100, firmware: app.efw, busy: 1, files: ["
        '{name: a.txt, text: "hi"}, {name: b.bin, hex: "0aff"}, {name: c.bin, path: blob.bin}]}'
    )
    (spec,) = network_specs(load_bus_config(_config(tmp_path, foe)))
    assert spec.foe is not None
    assert (spec.foe.password, spec.foe.capacity, spec.foe.firmware, spec.foe.busy) == (
        0x1234,
        100,
        "app.efw",
        1,
    )
    assert spec.foe.files == [("a.txt", b"hi"), ("b.bin", b"\x0a\xff"), ("c.bin", b"\0\1\2")]
    # The SII the simulator runs announces FoE, so the slave gets an FoE server.
    word = spec.sii[2 * sii_word.MBX_PROTOCOL : 2 * sii_word.MBX_PROTOCOL + 2]
    assert int.from_bytes(word, "little") & mailbox.PROTOCOL_FOE
    net = SimNetwork(manual_clock_ns=0)
    assert net.add_slave(spec) == 0


def test_defaults_are_the_simulators(tmp_path: Path) -> None:
    (spec,) = network_specs(load_bus_config(_config(tmp_path, "{}")))
    assert spec.foe is not None
    default = FoeSpec()
    assert (spec.foe.capacity, spec.foe.password, spec.foe.firmware, spec.foe.busy) == (
        default.capacity,
        None,
        "firmware.efw",
        0,
    )


@pytest.mark.parametrize(
    ("foe", "message"),
    [
        ("{files: [{name: a, text: x}, {name: a, text: y}]}", "file 'a' is given twice"),
        ("{files: [{name: a, path: nowhere.bin}]}", "file 'a': cannot read"),
        ("{capacity: 2, files: [{name: a, text: abc}]}", "take 3 bytes, more than"),
        ("{files: [{name: a, text: x, hex: '00'}]}", "give exactly one of text, hex or path"),
        ("{files: [{name: a, hex: 'zz'}]}", "hex: not hexadecimal bytes"),
        ("{busy: -1}", "busy"),
    ],
)
def test_a_store_that_cannot_be_built_is_refused_clearly(
    tmp_path: Path, foe: str, message: str
) -> None:
    with pytest.raises(ConfigError, match=message):
        network_specs(load_bus_config(_config(tmp_path, foe)))


def test_a_device_without_foe_refuses_a_store(tmp_path: Path) -> None:
    cfg = load_bus_config(_config(tmp_path, "{}", esi=GENERIC_ESI))
    with pytest.raises(ConfigError, match=r"slave 'io': sim.foe: .* does not announce FoE"):
        network_specs(cfg)
