"""The real vendor ESI corpus (``shared/esi-vendor``, with ``SOURCES.txt``): finding it, the
buses its devices run on, and running them under our master, pysoem and ethercrab.

Used by the acceptance tests (``tests/acceptance/test_vendor_esi.py``) and by
``scripts/esi_matrix.py``, which writes the results matrix of ``docs/devices.md``. The files are
read where they are, never copied into the project.

Every device (type and revision) of every file runs as a virtual slave, many of them on one
bus: a bus is a line of devices of one or more files, generated as a bus configuration
(``bus_yaml_for_devices``) that the simulator and the master both open.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ether_ros._native import protocol
from ether_ros.config import types as dt
from ether_ros.config.bus import BusConfig, SlaveConfig, default_sim_device
from ether_ros.config.esi import EsiDevice, is_dictionary_file, load_esi_file
from ether_ros.config.process import ProcessLayout, ProcessVariable
from ether_ros.netns import netns_command
from ether_ros.sim.spec import ESC_REGISTER_OBJECTS, bus_order, loopback_pairs, slave_spec

#: Where the corpus is when ``ETHER_ROS_VENDOR_ESI`` does not say: ``shared/esi-vendor`` in a
#: folder above the project (``/work/shared/esi-vendor`` for ``/work/main``).
VENDOR_ENV = "ETHER_ROS_VENDOR_ESI"
VENDOR_SUBDIR = Path("shared") / "esi-vendor"
#: Buses of the CI acceptance: the big Beckhoff files alone, the rest together.
BUS_GROUPS: tuple[tuple[str, tuple[str, ...]], ...] = (
    ("beckhoff_el1", ("Beckhoff EL1xxx.xml",)),
    ("beckhoff_el2", ("Beckhoff EL2xxx.xml",)),
    # 147 Sercos drives, their dictionaries in the folder beside the file.
    ("beckhoff_ax5", ("Beckhoff AX5xxx.xml",)),
    (
        "beckhoff_other",
        (
            "Beckhoff EK11xx.xml",
            "Beckhoff EL15xx.xml",
            "Beckhoff EL3xxx.xml",
            "Beckhoff EL9xxx.xml",
            "Beckhoff EP5xxx.xml",
        ),
    ),
)
#: The group of every file no other group names.
OTHER_VENDORS = "vendors"
#: How long a simulator of corpus devices may take to start: it parses multi-megabyte vendor
#: files, which on a loaded shared machine can exceed SimProcess's default 30 s.
SIM_READY_S = 180.0
#: Devices on a representative bus (the ethercrab probe holds 16 subdevices).
REPRESENTATIVE = 12


def vendor_dir(start: Path | None = None) -> Path | None:
    """The corpus folder, or None when there is none."""
    env = os.environ.get(VENDOR_ENV)
    if env:
        p = Path(env)
        return p if p.is_dir() else None
    here = (start or Path(__file__)).resolve()
    for parent in here.parents:
        candidate = parent / VENDOR_SUBDIR
        if candidate.is_dir():
            return candidate
    return None


def no_vendor_dir_reason(start: Path | None = None) -> str:
    """Why ``vendor_dir`` found nothing, naming where it looked (a test's skip reason)."""
    env = os.environ.get(VENDOR_ENV)
    if env:
        return f"no vendor ESI corpus: {VENDOR_ENV}={env} is not a directory"
    here = (start or Path(__file__)).resolve()
    return (
        f"no vendor ESI corpus: no {VENDOR_SUBDIR} in {here.parent} or any folder above it"
        f" (or set {VENDOR_ENV})"
    )


def vendor_files(root: Path) -> list[Path]:
    """Every ESI file of the corpus, sorted by path: dictionary files (Beckhoff's AX5000
    keeps its dictionaries in a folder beside the ESI) are read for the devices that name
    them, not as files of their own."""
    return sorted(p for p in root.rglob("*.xml") if p.is_file() and not is_dictionary_file(p))


def bus_devices(files: Iterable[Path]) -> list[EsiDevice]:
    """Every device that is on a bus (not a passive terminal) of ``files``, in file order."""
    return [d for f in files for d in load_esi_file(f).devices if not d.passive]


def bus_groups(root: Path) -> dict[str, list[Path]]:
    """The corpus files by CI bus group (``BUS_GROUPS``, the rest in ``vendors``)."""
    files = vendor_files(root)
    groups: dict[str, list[Path]] = {}
    named = set()
    for name, members in BUS_GROUPS:
        chosen = [f for f in files if f.name in members]
        if chosen:
            groups[name] = chosen
            named.update(chosen)
    rest = [f for f in files if f not in named]
    if rest:
        groups[OTHER_VENDORS] = rest
    return groups


def representative(devices: Sequence[EsiDevice], n: int = REPRESENTATIVE) -> list[EsiDevice]:
    """Up to ``n`` devices spread over ``devices`` (newest revision of each type, types taken
    at even steps), so a short bus still shows the file's kinds of devices."""
    newest: dict[str, EsiDevice] = {}
    for d in devices:
        key = f"{d.vendor_id}:{d.product_code}:{d.type_name}"
        if key not in newest or d.revision > newest[key].revision:
            newest[key] = d
    types = list(newest.values())
    if len(types) <= n:
        return types
    step = len(types) / n
    return [types[int(k * step)] for k in range(n)]


#: Largest representative bus (the ethercrab probe holds 16 subdevices) and the devices a
#: file gives to it.
REPRESENTATIVE_BUS = 16
PER_FILE = 6


def sync0_latched_one_buffer_inputs(device: EsiDevice) -> bool:
    """Whether ``device`` hands its inputs over in a one-buffer (mailbox-mode) SyncManager that
    its firmware fills on SYNC0 (Beckhoff's AX5000): such an SM holds data for one read per
    SYNC0 period, so a master that does not send in phase with SYNC0 — the ethercrab probe
    sends on its own timer — misses a read (working counter one short) whenever two of its
    frames fall into one period, on a real device as in the simulator (docs/devices.md)."""
    one_buffer = any(
        sm.role == "Inputs" and sm.control & protocol.sm.MODE_MASK == protocol.sm.MODE_MAILBOX
        for sm in device.sync_managers
    )
    sync0 = any(m.assign_activate >> 8 & protocol.dc.ACTIVATE_SYNC0 for m in device.dc_opmodes)
    return one_buffer and sync0


def representative_buses(root: Path) -> list[tuple[str, list[EsiDevice]]]:
    """Buses of at most ``REPRESENTATIVE_BUS`` devices on which every file of the corpus is
    represented (up to ``PER_FILE`` of its devices, ``representative``), a file's devices on
    one bus; named after their first file."""
    buses: list[tuple[str, list[EsiDevice]]] = []
    current: list[EsiDevice] = []
    name = ""
    for f in vendor_files(root):
        chosen = representative(bus_devices([f]), PER_FILE)
        if not chosen:
            continue
        if current and len(current) + len(chosen) > REPRESENTATIVE_BUS:
            buses.append((name, current))
            current = []
        if not current:
            name = re.sub(r"[^a-z0-9]+", "_", f.stem.lower()).strip("_")
        current.extend(chosen)
    if current:
        buses.append((name, current))
    return buses


# --------------------------------------------------------------------------------------------
# Process data that really flows: an output of each loopback slave comes back in an input.


@dataclass(frozen=True)
class Echo:
    """One output written to a slave and the input its loopback model copies it to."""

    slave: str
    output: ProcessVariable
    input: ProcessVariable
    value: int | bool


def echo_checks(cfg: BusConfig) -> list[Echo]:
    """For every slave running the ``loopback`` model: its first output → input pair of a
    number type in real (not virtual) PDOs, with a value that is not the power-on zero."""
    checks: list[Echo] = []
    for s in bus_order(cfg):
        if default_sim_device(s.esi) != "loopback" or s.sim.device not in (None, "loopback"):
            continue
        layout = s.layout
        for out_i, out_s, in_i, in_s in loopback_pairs(s.esi):
            if _repeated(s.esi, out_i, out_s) or _repeated(s.esi, in_i, in_s):
                # One object in several PDOs (the channels of a two-axis Sercos drive map
                # the same IDNs): the model keeps one value per object, so which channel's
                # output comes back is not defined.
                continue
            out = _variable(layout.outputs, out_i, out_s)
            inp = _variable(layout.inputs, in_i, in_s)
            if out is None or inp is None or out.dtype.kind not in ("bool", "int", "uint"):
                continue
            checks.append(Echo(s.name, out, inp, _value(out)))
            break
    return checks


def _repeated(device: EsiDevice, index: int, sub: int) -> bool:
    """Whether entry ``index:sub`` is mapped by more than one (non-virtual) PDO."""
    pdos = [p for p in (*device.rx_pdos, *device.tx_pdos) if not p.virtual]
    return sum(any((e.index, e.subindex) == (index, sub) for e in p.entries) for p in pdos) > 1


def _variable(vs: Sequence[ProcessVariable], index: int, sub: int) -> ProcessVariable | None:
    if index in ESC_REGISTER_OBJECTS:
        return None
    return next((v for v in vs if (v.index, v.subindex) == (index, sub)), None)


def _value(v: ProcessVariable) -> int | bool:
    if v.dtype.kind == "bool":
        return True
    return (0x5A5A5A5A5A5A5A5A & ((1 << (v.bit_length - 1)) - 1)) or 1


# --------------------------------------------------------------------------------------------
# ethercrab: the probe binary of tests/ethercrab_probe


@dataclass(frozen=True)
class Sizes:
    """Process data bytes of one slave, each direction."""

    output_bytes: int
    input_bytes: int


def own_assignment_sizes(slave: SlaveConfig) -> Sizes:
    """The process data of a master that writes no PDO assignment (ethercrab, SOEM): with CoE
    it reads the device's own assignment (0x1C10 + SM, then each PDO's mapping) for each
    process data SyncManager, without CoE it takes the SII's PDOs (the ESI's defaults). A
    device whose dictionary assigns other PDOs than the ESI's ``Sm`` defaults (EL2212: the MTO
    PDOs too) then has other sizes than under our master, which writes the ESI's assignment,
    as TwinCAT and IgH do."""
    d = slave.esi
    if d.mailbox is None or not d.mailbox.coe:
        layout = ProcessLayout.for_device(d)
        return Sizes(layout.output_bytes, layout.input_bytes)
    values: dict[tuple[int, int], bytes] = {
        (e[0], e[1]): bytes(e[7] or b"") for e in slave_spec(slave, 0).entries
    }

    def count(index: int) -> int:
        return (values.get((index, 0)) or b"\0")[0]

    sizes = {"Outputs": 0, "Inputs": 0}
    for sm in d.sync_managers:
        if not sm.is_process_data:
            continue
        assign = 0x1C10 + sm.number
        bits = 0
        for k in range(1, count(assign) + 1):
            pdo = int.from_bytes(values.get((assign, k), b"\0\0")[:2], "little")
            for j in range(1, count(pdo) + 1):
                bits += (values.get((pdo, j)) or b"\0")[0]  # mapping entry: bit length in byte 0
        sizes[sm.role] += (bits + 7) // 8
    return Sizes(sizes["Outputs"], sizes["Inputs"])


#: Process data bytes in one of the ethercrab probe's LRW datagrams: its PDU storage holds
#: ``PduStorage::element_size(1100)`` per frame (``tests/ethercrab_probe/src/main.rs``).
ETHERCRAB_LRW_BYTES = 1100


def ethercrab_expected_wkc(cfg: BusConfig) -> int:
    """The working counter ethercrab reports for the bus: its process image holds every
    slave's inputs, then every slave's outputs (ethercrab ``configure_fmmus``: "IIIIOOOO"), sent
    in LRWs of ``ETHERCRAB_LRW_BYTES`` whose counters it adds up. In each LRW a slave counts +1
    when some of its inputs are in it and +2 when some of its outputs are (ESC datasheet,
    "Working counter"), so a slave whose data spans two LRWs counts in both."""
    sizes = [own_assignment_sizes(s) for s in bus_order(cfg)]  # ethercrab: position order
    ranges: list[tuple[int, int, int]] = []  # (start, end, count)
    at = 0
    for size in sizes:
        ranges.append((at, at + size.input_bytes, 1))
        at += size.input_bytes
    for size in sizes:
        ranges.append((at, at + size.output_bytes, 2))
        at += size.output_bytes
    wkc = 0
    for chunk in range(0, at, ETHERCRAB_LRW_BYTES):
        end = chunk + ETHERCRAB_LRW_BYTES
        wkc += sum(n for lo, hi, n in ranges if lo < hi and lo < end and hi > chunk)
    return wkc


def run_ethercrab(
    probe: Path,
    interface: str,
    cfg: BusConfig,
    cycles: int = 2000,
    timeout_s: float = 240,
    netns: str | None = None,
) -> dict[str, Any]:
    """Run the ethercrab probe on ``interface`` (in network namespace ``netns``: see
    ``ether_ros.netns``) for the bus ``cfg``; its JSON report (with ``error`` set, and
    ``exit`` its status, when something failed)."""
    argv = [str(probe), "--interface", interface, "--cycles", str(cycles),
            "--cycle-us", str(cfg.bus.cycle_us),
            "--expect-slaves", str(len(cfg.slaves)),
            "--expect-wkc", str(ethercrab_expected_wkc(cfg))]  # fmt: skip
    if cfg.bus.dc.enabled:
        argv += ["--dc", "--shift-us", str(int(cfg.bus.dc.sync0_shift_us))]
    done = subprocess.run(
        netns_command(netns, argv), capture_output=True, text=True, timeout=timeout_s, check=False
    )
    lines = [ln for ln in done.stdout.splitlines() if ln.startswith("{")]
    if not lines:
        return {"error": f"no report (exit {done.returncode}): {done.stderr[-500:]}",
                "exit": done.returncode}  # fmt: skip
    result: dict[str, Any] = json.loads(lines[-1])
    result["exit"] = done.returncode
    return result


# --------------------------------------------------------------------------------------------
# The results matrix


@dataclass
class DeviceResult:
    """One device's row of the matrix."""

    file: str
    type_name: str
    revision: int
    product_code: int
    loads: bool = True
    passive: bool = False
    simulated: str = ""  # '' not tried, 'yes', or why not
    ours: str = ""
    pysoem: str = ""
    ethercrab: str = ""
    notes: list[str] = field(default_factory=list)

    @property
    def key(self) -> tuple[str, str, int]:
        return (self.file, self.type_name, self.revision)


def slave_index(message: str, names: Sequence[str]) -> int | None:
    """The position of the slave an error message names (``slave 7 (name)``), if any."""
    m = re.search(r"slave (\d+) \(([^)]*)\)", message)
    if m and m.group(2) in names:
        return names.index(m.group(2))
    m = re.search(r"slaves\[(\d+)\]", message)
    if m:
        return int(m.group(1))
    m = re.search(r"slave '([^']*)'", message)
    if m and m.group(1) in names:
        return names.index(m.group(1))
    return None


def code_name(code: int) -> str:
    return dt.BY_CODE[code].name if code in dt.BY_CODE else f"{code:#x}"
