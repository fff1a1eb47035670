#!/usr/bin/env python3
"""The results matrix of docs/devices.md: every device of every file of the real vendor ESI
corpus (``shared/esi-vendor`` or ``ETHER_ROS_VENDOR_ESI``) × (loads, simulated, our master to
OP, pysoem to OP, ethercrab to OP).

    scripts/esi_matrix.py [--write docs/devices.md] [--only NAME-PART] [--skip-ethercrab]

Needs root (veth pairs, network namespaces) and the ethercrab probe (built here with cargo).
Each file's devices run on one simulated bus per master (ethercrab: 16 at a time); a device
that stops a bus is named by the master's error (or found by halving), marked, and the bus
runs again without it. Prints the matrix; ``--write`` puts it between the matrix markers of
the given file.
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import shutil
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "python"))

from ether_ros.config.bus import load_bus_config  # noqa: E402
from ether_ros.config.esi import EsiDevice, load_esi_file  # noqa: E402
from ether_ros.config.from_esi import bus_yaml_for_devices  # noqa: E402
from ether_ros.errors import EtherRosError  # noqa: E402
from ether_ros.master import Bus  # noqa: E402
from ether_ros.sim.proof import OP, SimProcess, SoemBus  # noqa: E402
from ether_ros.sim.spec import bus_order, device_spec  # noqa: E402
from ether_ros.testing.netns import VethPair  # noqa: E402
from ether_ros.testing.wait import wait_for  # noqa: E402
from ether_ros.tools.vendor_corpus import (  # noqa: E402
    SIM_READY_S,
    DeviceResult,
    no_vendor_dir_reason,
    own_assignment_sizes,
    run_ethercrab,
    slave_index,
    vendor_dir,
    vendor_files,
)

START = "<!-- esi-matrix:start -->"
END = "<!-- esi-matrix:end -->"
PROBE_DIR = REPO / "tests" / "ethercrab_probe"
ETHERCRAB_BUS = 16

# A bus run: the devices in, for each one either "" (reached OP) or why not.
Runner = Callable[[list[EsiDevice], Path], list[str]]


def run_ours(devices: list[EsiDevice], yml: Path) -> list[str]:
    with (
        VethPair.create(netns=True) as veth,
        SimProcess(yml, veth.slave, veth.netns, ready_timeout=SIM_READY_S),
    ):
        cfg = load_bus_config(yml, interface=veth.master)
        with Bus.open(cfg) as bus:
            bus.start()
            assert bus.layout is not None
            expected = [f.expected_wkc for f in bus.layout.frames]
            wait_for(
                "the working counters",
                lambda: [f["last_wkc"] for f in bus.stats()["frames"]] == expected,
                timeout=20,
            )
            return ["" if s.state == "OP" else f"{s.state} {s.text}" for s in bus.states()]


def run_pysoem(devices: list[EsiDevice], yml: Path) -> list[str]:
    cfg = load_bus_config(yml)
    with (
        VethPair.create(netns=True, master_netns=True) as veth,
        SimProcess(yml, veth.slave, veth.netns, ready_timeout=SIM_READY_S),
    ):
        soem = SoemBus(cfg, veth.master, netns=veth.master_netns)
        try:
            soem.scan()
            soem.set_watchdog(2000)
            with contextlib.suppress(EtherRosError):
                soem.configure()
            soem.request_op(timeout_s=10)
            states = soem.states()
            out = []
            for s, (state, code) in zip(soem.slaves, states, strict=True):
                out.append("" if state == OP else f"state {state:#x} AL {code:#06x}")
                del s
            return out
        finally:
            soem.close()


def run_ethercrab_bus(devices: list[EsiDevice], yml: Path, probe: Path) -> list[str]:
    cfg = load_bus_config(yml)
    with (
        VethPair.create(netns=True, master_netns=True) as veth,
        SimProcess(yml, veth.slave, veth.netns, ready_timeout=SIM_READY_S),
    ):
        result = run_ethercrab(probe, veth.master, cfg, cycles=500, netns=veth.master_netns)
    if result.get("exit") == 0 and result.get("op") and not result.get("wkc_errors"):
        sizes = []
        for out, inp, s in zip(result["outputs"], result["inputs"], bus_order(cfg), strict=True):
            own = own_assignment_sizes(s)
            ok = (len(out) // 2, len(inp) // 2) == (own.output_bytes, own.input_bytes)
            sizes.append("" if ok else "process data size differs")
        return sizes
    # The bus as a whole failed: ``isolate`` finds the devices to blame.
    raise RuntimeError(str(result.get("error") or f"wkc errors {result.get('wkc_errors')}"))


def isolate(devices: list[EsiDevice], run: Runner, tmp: Path) -> list[str]:
    """Run ``devices`` as one bus; when the bus as a whole fails, find the devices to blame
    (named by the error, else by halving) and run the rest again."""
    if not devices:
        return []
    yml = bus_yaml_for_devices(devices, tmp / f"bus{time.monotonic_ns()}.yaml")
    try:
        return run(devices, yml)
    except Exception as exc:  # any master's failure (pysoem raises its own types) is a result
        message = " ".join(f"{type(exc).__name__}: {exc}".split())[:160]
    names = [s.name for s in load_bus_config(yml).slaves]
    k = slave_index(message, names)
    if k is not None:
        rest = isolate(devices[:k] + devices[k + 1 :], run, tmp)
        return [*rest[:k], message, *rest[k:]]
    if len(devices) == 1:
        return [message]
    half = len(devices) // 2
    return isolate(devices[:half], run, tmp) + isolate(devices[half:], run, tmp)


def simulate(d: EsiDevice) -> str:
    from ether_ros._native import SimNetwork

    try:
        SimNetwork(seed=1).add_slave(device_spec(d, name="s", sim_device="loopback"))
    except (EtherRosError, ValueError) as exc:
        return " ".join(str(exc).split())[:120]
    return "yes"


def mark(results: Sequence[DeviceResult], outcome: Sequence[str], column: str) -> None:
    for r, why in zip(results, outcome, strict=True):
        setattr(r, column, "OP" if why == "" else f"no: {why}")


def matrix(root: Path, only: str | None, ethercrab: bool) -> list[DeviceResult]:
    probe = None
    if ethercrab:
        cargo = shutil.which("cargo") or str(Path.home() / ".cargo" / "bin" / "cargo")
        subprocess.run([cargo, "build", "--release", "--locked", "-q"], cwd=PROBE_DIR, check=True)
        probe = PROBE_DIR / "target" / "release" / "ethercrab-probe"
    rows: list[DeviceResult] = []
    for f in vendor_files(root):
        if only and only not in f.name:
            continue
        rel = str(f.relative_to(root))
        esi = load_esi_file(f)
        file_rows = [
            DeviceResult(rel, d.type_name, d.revision, d.product_code, passive=d.passive)
            for d in esi.devices
        ]
        for w in esi.skipped_devices:
            file_rows.append(DeviceResult(rel, w.message, 0, 0, loads=False))
        rows.extend(file_rows)
        active = [(r, d) for r, d in zip(file_rows, esi.devices, strict=False) if not d.passive]
        for r, d in active:
            r.simulated = simulate(d)
        runnable = [(r, d) for r, d in active if r.simulated == "yes"]
        devices = [d for _, d in runnable]
        results = [r for r, _ in runnable]
        print(f"{rel}: {len(esi.devices)} devices, {len(devices)} on the bus", flush=True)
        with tempfile.TemporaryDirectory(prefix="esi_matrix_") as tmp:
            mark(results, isolate(devices, run_ours, Path(tmp)), "ours")
            mark(results, isolate(devices, run_pysoem, Path(tmp)), "pysoem")
            if probe is not None:
                for k in range(0, len(devices), ETHERCRAB_BUS):
                    chunk = devices[k : k + ETHERCRAB_BUS]
                    outcome = isolate(
                        chunk, lambda ds, y: run_ethercrab_bus(ds, y, probe), Path(tmp)
                    )
                    mark(results[k : k + ETHERCRAB_BUS], outcome, "ethercrab")
    return rows


def _cell(value: str) -> str:
    if value in ("", "yes", "OP"):
        return value or "—"
    return "no" if value.startswith("no") else value


def render(rows: Sequence[DeviceResult], command: str) -> str:
    files = sorted({r.file for r in rows})
    out = [
        START,
        "",
        f"Made by `{command}` ({time.strftime('%Y-%m-%d')}). Per file: devices (type and",
        "revision) that load, are passive terminals (no ESC: not on a bus), run as virtual",
        "slaves, and reach OP under each master (every device of the file on one bus;",
        "ethercrab 16 at a time).",
        "",
        "| file | devices | passive | simulated | our master OP | pysoem OP | ethercrab OP |",
        "|---|---|---|---|---|---|---|",
    ]
    for f in files:
        fr = [r for r in rows if r.file == f]
        bus = [r for r in fr if r.loads and not r.passive]

        def count(col: str, bus: list[DeviceResult] = bus) -> str:
            return f"{sum(1 for r in bus if getattr(r, col) in ('OP', 'yes'))}/{len(bus)}"

        out.append(
            f"| {f} | {sum(1 for r in fr if r.loads)} | {sum(1 for r in fr if r.passive)} | "
            f"{count('simulated')} | {count('ours')} | {count('pysoem')} | {count('ethercrab')} |"
        )
    out += ["", "Every device (— : not tried; the reasons of a `no` follow the table):", ""]
    out += [
        "| file | device | revision | load | simulate | ours | pysoem | ethercrab |",
        "|---|---|---|---|---|---|---|---|",
    ]
    reasons: list[str] = []
    for r in rows:
        if r.passive:
            cells = ["yes", "passive", "—", "—", "—"]
        elif not r.loads:
            cells = ["no", "—", "—", "—", "—"]
        else:
            cells = ["yes", *(_cell(getattr(r, c)) for c in ("simulated", "ours", "pysoem",
                                                             "ethercrab"))]  # fmt: skip
        out.append(f"| {r.file} | {r.type_name} | {r.revision:#010x} | " + " | ".join(cells) + " |")
        for c in ("simulated", "ours", "pysoem", "ethercrab"):
            value = getattr(r, c)
            if value.startswith("no") or (c == "simulated" and value not in ("", "yes")):
                reasons.append(f"- {r.type_name} {r.revision:#010x} ({r.file}), {c}: {value}")
    if reasons:
        out += ["", *reasons]
    out += ["", END]
    return "\n".join(out)


def main() -> int:
    logging.basicConfig(level=logging.ERROR)
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--write", type=Path, help="put the matrix into this file (between markers)")
    p.add_argument("--only", help="only files whose name contains this")
    p.add_argument("--skip-ethercrab", action="store_true")
    args = p.parse_args()
    root = vendor_dir(REPO)
    if root is None:
        print(no_vendor_dir_reason(REPO), file=sys.stderr)
        return 2
    rows = matrix(root, args.only, not args.skip_ethercrab)
    text = render(rows, "scripts/esi_matrix.py --write docs/devices.md")
    if args.write is not None:
        doc = args.write.read_text()
        if START in doc and END in doc:
            doc = doc[: doc.index(START)] + text + doc[doc.index(END) + len(END) :]
        else:
            doc = doc.rstrip() + "\n\n" + text + "\n"
        args.write.write_text(doc)
    else:
        print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
