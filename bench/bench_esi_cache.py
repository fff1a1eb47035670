"""A command's start with a cold and a warm ESI cache (config/esi_cache.py, issue 28 item 7).

`ether-ros esi FILE` (it parses the file and lists its devices) on each of the vendor's big
files (`../shared/esi-vendor/beckhoff`, the fixtures `tests/data/esi` when it is missing), as a
user runs it: a new process each time. Cold: an empty cache directory (the parse, then the entry
written); warm: the same command again. The baseline, in the same run, is the same process
doing no parse at all (`ether-ros --version`): the interpreter's and the package's own start.
"""

from __future__ import annotations

import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from report import Report

REPO = Path(__file__).resolve().parent.parent
VENDOR = REPO.parent / "shared" / "esi-vendor" / "beckhoff"


def _files() -> list[Path]:
    if VENDOR.is_dir():
        return sorted(VENDOR.glob("*.xml"))
    return sorted((REPO / "tests" / "data" / "esi").glob("*.xml"))[:4]


def _run(args: list[str], cache: Path) -> float:
    env = {**os.environ, "ETHER_ROS_CACHE_DIR": str(cache), "ETHER_ROS_ESI_CACHE": "1"}
    t0 = time.perf_counter()
    subprocess.run(
        [sys.executable, "-m", "ether_ros.cli.main", *args],
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        check=False,
    )
    return time.perf_counter() - t0


def run(report: Report) -> None:
    repeats = 1 if report.quick else 3
    rows = []
    with tempfile.TemporaryDirectory(prefix="bench-esi-cache-") as tmp:
        floor = statistics.median(_run(["--version"], Path(tmp)) for _ in range(repeats))
        for path in _files():
            cold, warm = [], []
            for i in range(repeats):
                cache = Path(tmp) / f"{path.stem}-{i}"
                cold.append(_run(["esi", str(path)], cache))
                warm.append(_run(["esi", str(path)], cache))
            c, w = statistics.median(cold), statistics.median(warm)
            rows.append(
                [
                    path.name,
                    f"{path.stat().st_size / 1e6:.1f} MB",
                    f"{c:.2f}",
                    f"{w:.2f}",
                    f"{c / w:.1f}×",
                    f"{max(w - floor, 0.0):.2f}",
                ]
            )
            report.value(path.stem, {"cold_s": c, "warm_s": w, "floor_s": floor})
    report.text(
        f"`ether-ros esi FILE` in a new process, median of {repeats}; the floor is "
        f"`ether-ros --version` in the same run: {floor:.2f} s."
    )
    report.table(
        ["file", "size", "cold cache (s)", "warm cache (s)", "cold / warm", "warm − floor (s)"],
        rows,
    )
