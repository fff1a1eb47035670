"""Bring-up time of `config/line128.yaml` (128 slaves: Laelaps II legs, two-axis CiA 402 drives
and generic I/O boxes, DC), this tree against a baseline tree, in the same run.

Setup: the simulator (`ether-ros sim`) in its own process, pinned to CPU 0, in its own network
namespace across a veth pair; on the near end a fresh Python process per measurement opens the
bus (`Bus.open`: scan, SII, checks) and starts it (`Bus.start`: every slave to OP, with DC
delay measurement, drift compensation and SYNC0), then stops it. The two trees alternate,
`RUNS` times each, against the same simulator; the table gives each tree's median and range.

The baseline ("before") is the master's Python code of another commit, `BRINGUP_BASE` (default:
the merge base of HEAD and `main`), extracted with `git archive` and run with this tree's native
module (the Rust core is the same unless the two commits differ there; the section says which
commit it is). This tree is "after".
"""

from __future__ import annotations

import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

BENCH = Path(__file__).resolve().parent
if str(BENCH) not in sys.path:
    sys.path.insert(0, str(BENCH))

from bench_master import pinned_simulator  # noqa: E402
from ether_ros.testing.netns import VethPair  # noqa: E402
from report import BenchSkipped, Report  # noqa: E402

REPO = BENCH.parent
LINE = REPO / "config" / "line128.yaml"
RUNS = 3

# Runs in a fresh interpreter with PYTHONPATH at the tree being measured.
MEASURE = """
import json, sys, time
from ether_ros.config import load_bus_config
from ether_ros.master import Bus
cfg = load_bus_config(sys.argv[1], interface=sys.argv[2])
t0 = time.monotonic()
bus = Bus.open(cfg)
t1 = time.monotonic()
bus.start()
t2 = time.monotonic()
states = {s.state for s in bus.states()}
bus.close()
import ether_ros.master.bus as b
print(json.dumps({"open_s": t1 - t0, "start_s": t2 - t1, "states": sorted(states),
                  "code": b.__file__}))
"""


def write_config(directory: Path) -> Path:
    """line128 with absolute ESI paths and no real-time demands on the shared machine (only
    the acyclic path is measured)."""
    import yaml

    doc = yaml.safe_load(LINE.read_text())
    doc["esi"] = [str((LINE.parent / p).resolve()) for p in doc["esi"]]
    doc["bus"]["realtime"] = {"policy": "other", "cpu": None, "lock_memory": False}
    path = directory / "line128.yaml"
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return path


def baseline_tree(directory: Path) -> tuple[Path, str]:
    """The baseline commit's python/ tree, with this tree's native module."""
    base = os.environ.get("BRINGUP_BASE")
    if not base:
        r = subprocess.run(
            ["git", "-C", str(REPO), "merge-base", "HEAD", "main"],
            capture_output=True, text=True, check=False,
        )  # fmt: skip
        if r.returncode != 0:
            raise BenchSkipped(f"no baseline commit (git merge-base HEAD main): {r.stderr}")
        base = r.stdout.strip()
    out = directory / "before"
    out.mkdir()
    archive = subprocess.run(
        ["git", "-C", str(REPO), "archive", base, "python"], capture_output=True, check=False
    )
    if archive.returncode != 0:
        raise BenchSkipped(f"git archive {base} failed: {archive.stderr.decode()[-300:]}")
    subprocess.run(["tar", "-x", "-C", str(out)], input=archive.stdout, check=True)
    for so in (REPO / "python" / "ether_ros").glob("_native*.so"):
        (out / "python" / "ether_ros" / so.name).write_bytes(so.read_bytes())
    return out / "python", base[:12]


def measure(tree: Path, config: Path, interface: str, cwd: Path) -> dict[str, Any]:
    env = dict(os.environ, PYTHONPATH=str(tree))
    r = subprocess.run(
        [sys.executable, "-c", MEASURE, str(config), interface],
        capture_output=True, text=True, env=env, cwd=cwd, timeout=300, check=False,
    )  # fmt: skip
    if r.returncode != 0:
        return {"error": (r.stderr.strip() or r.stdout.strip())[-300:]}
    result: dict[str, Any] = json.loads(r.stdout.strip().splitlines()[-1])
    if not str(result["code"]).startswith(str(tree)):
        return {"error": f"measured {result['code']}, not the tree {tree}"}
    return result


def _cell(values: list[float]) -> str:
    if not values:
        return "failed"
    return f"{statistics.median(values):.2f} ({min(values):.2f}–{max(values):.2f})"


def run(report: Report) -> None:
    try:
        import ether_ros._native  # noqa: F401
    except ImportError as e:
        raise BenchSkipped(f"ether_ros._native is not built: {e}") from None
    runs = 1 if report.quick else RUNS
    trees: dict[str, list[dict[str, Any]]] = {"before": [], "after": []}
    with tempfile.TemporaryDirectory(prefix="bench_bringup_") as tmp:
        directory = Path(tmp)
        before, base = baseline_tree(directory)
        after = REPO / "python"
        config = write_config(directory)
        with (
            VethPair.create(netns=True) as veth,
            pinned_simulator(config, veth.slave, veth.netns),
        ):
            for k in range(runs):
                for name, tree in (("before", before), ("after", after)):
                    print(f"[bringup] {name} run {k + 1}/{runs}", flush=True)
                    trees[name].append(measure(tree, config, veth.master, directory))
    rows = []
    for name in ("before", "after"):
        ok = [r for r in trees[name] if "error" not in r and r["states"] == ["OP"]]
        errors = [r.get("error", f"states {r.get('states')}") for r in trees[name] if r not in ok]
        rows.append(
            [
                f"{name} ({base})" if name == "before" else f"{name} (this tree)",
                _cell([r["open_s"] for r in ok]),
                _cell([r["start_s"] for r in ok]),
                _cell([r["open_s"] + r["start_s"] for r in ok]),
                errors[0][:120] if errors else "",
            ]
        )
        report.value(name, trees[name])
    report.value("base", base)
    report.text(
        f"Bring-up of config/line128.yaml (128 slaves, DC), {runs} run(s) per tree, alternating, "
        "against one simulator pinned to CPU 0 in a network namespace across a veth pair; a "
        "fresh Python process per run; seconds, median (range). open = `Bus.open` (scan, SII, "
        "checks); start = `Bus.start` (every slave to OP: mailbox, PREOP configuration, DC "
        "delays, drift compensation, SYNC0, SAFEOP, OP). before = the master's Python code of "
        f"commit {base} with this tree's native module; after = this tree. The machine is a "
        "shared 2-core VM: runs are noisy."
    )
    report.table(["tree", "open s", "start s", "bring-up s", "error"], rows)
