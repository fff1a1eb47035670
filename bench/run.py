"""Run the benchmarks in bench/ and write their results into docs/benchmarks.md.

Every ``bench/bench_<name>.py`` exposes ``run(report: Report) -> None``. This runner imports each
one, runs it, and replaces that benchmark's section of docs/benchmarks.md (between
``<!-- bench:<name> -->`` markers), stamped with the command that produced it, the date and the
host; sections of benchmarks not run this time are kept. Raw numbers go to
``bench/results/<name>.json``.

    python bench/run.py                 # everything (what `make bench` runs)
    python bench/run.py --only sim      # one benchmark (name without "bench_"; repeatable)
    python bench/run.py --quick         # shorter runs, for a smoke test
    python bench/run.py --list
"""

from __future__ import annotations

import argparse
import datetime
import importlib.util
import json
import os
import platform
import re
import sys
import traceback
from pathlib import Path
from types import ModuleType

BENCH = Path(__file__).resolve().parent
REPO = BENCH.parent
DOC = REPO / "docs" / "benchmarks.md"
RESULTS = BENCH / "results"
sys.path.insert(0, str(BENCH))

from report import BenchSkipped, Report  # noqa: E402

HEADER = """# Benchmarks

Measured on the development VM by `make bench` (`python bench/run.py`); each section says which
command produced it, when, and on what host. Timing varies from run to run on a shared VM, so
every benchmark measures its own baseline in the same run (cyclictest, a C echo responder) and
states results next to it. Sections are rewritten by the runner; edit the benchmark, not this
file.

## How the benchmarks work
- `bench/run.py` runs every `bench/bench_*.py` (`run(report)`), `--only NAME`, `--quick`.
- `bench/c/echo.c`: the minimal EtherCAT responder (AF_PACKET; +1 on every datagram's working
  counter, sets source-MAC bit 0x02, sends the frame back) — the floor for any simulator.
- `bench/c/rtt.c`: sends LRW frames (ping-pong, or paced at a rate with up to 256 in flight),
  matches answers by datagram index, prints round-trip percentiles as JSON.
- `bench/baseline.py`: builds the C tools (`cc -O2` into `bench/.build`), runs cyclictest and
  parses its histogram, runs the echo/probe pair, reads per-thread CPU time from `/proc`.
- `bench/bench_fuzz.py` (`make fuzz`): the long fuzz run of every input boundary — mutant
  corpora of the configurations and ESI files, proptest (frames, CDR, the simulated ESC),
  hypothesis (configuration values, ROS messages); counts, not times. `make test` runs the same
  harnesses with a fixed seed in seconds (the ESI and config corpora in a few minutes).
"""


def discover() -> dict[str, Path]:
    """Benchmark name -> module path, sorted by name."""
    found = {p.stem.removeprefix("bench_"): p for p in BENCH.glob("bench_*.py")}
    return dict(sorted(found.items()))


def load(name: str, path: Path) -> ModuleType:
    spec = importlib.util.spec_from_file_location(f"bench_{name}", path)
    if spec is None or spec.loader is None:
        raise ImportError(f"cannot import {path}")
    module = importlib.util.module_from_spec(spec)
    # Registered before it runs, as a normal import would be (dataclasses look their module up).
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    if not callable(getattr(module, "run", None)):
        raise ImportError(f"{path.name} has no run(report) function")
    return module


def host_line() -> str:
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return f"{platform.node()}, Linux {platform.release()}, {cpu}, {os.cpu_count()} CPUs"


def section(name: str, body: str, command: str) -> str:
    stamp = datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%d %H:%M UTC")
    return (
        f"<!-- bench:{name} -->\n## {name}\n\n"
        f"_`{command}` — {stamp} — {host_line()}_\n\n{body.rstrip()}\n<!-- /bench:{name} -->\n"
    )


def merge(existing: str, sections: dict[str, str]) -> str:
    """Replace or append the given sections, keep the others, refresh the header."""
    kept: dict[str, str] = {}
    for m in re.finditer(r"<!-- bench:(\w+) -->.*?<!-- /bench:\1 -->\n?", existing, re.S):
        kept[m.group(1)] = m.group(0).rstrip() + "\n"
    kept.update(sections)
    return HEADER + "\n" + "\n".join(kept[k] for k in sorted(kept))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="Run the benchmarks in bench/.")
    parser.add_argument("--only", action="append", metavar="NAME", help="run only this one")
    parser.add_argument("--quick", action="store_true", help="shorter runs (smoke test)")
    parser.add_argument("--list", action="store_true", help="list the benchmarks and exit")
    parser.add_argument("--no-write", action="store_true", help="print, don't touch the docs")
    args = parser.parse_args(argv)

    available = discover()
    if args.list:
        print("\n".join(available))
        return 0
    names = args.only or list(available)
    unknown = [n.removeprefix("bench_") for n in names if n.removeprefix("bench_") not in available]
    if unknown:
        print(f"unknown benchmark(s): {', '.join(unknown)} (have: {', '.join(available)})")
        return 2
    names = [n.removeprefix("bench_") for n in names]

    command = "python bench/run.py" + "".join(f" --only {n}" for n in args.only or [])
    command += " --quick" if args.quick else ""
    sections: dict[str, str] = {}
    failed = False
    RESULTS.mkdir(exist_ok=True)
    for name in names:
        print(f"[bench] {name} ...", flush=True)
        report = Report(name=name, quick=args.quick)
        try:
            load(name, available[name]).run(report)
            status = "ok"
        except BenchSkipped as e:
            report.text(f"**Skipped:** {e}")
            status = f"skipped: {e}"
        except Exception as e:  # a broken benchmark must not hide the others' results
            traceback.print_exc()
            report.text(f"**Failed:** `{type(e).__name__}: {e}`")
            status = f"failed: {e}"
            failed = True
        print(f"[bench] {name}: {status}", flush=True)
        print(report.markdown())
        sections[name] = section(name, report.markdown(), command)
        (RESULTS / f"{name}.json").write_text(
            json.dumps({"command": command, "quick": args.quick, **report.values}, indent=2) + "\n"
        )
    if not args.no_write:
        existing = DOC.read_text() if DOC.exists() else ""
        DOC.write_text(merge(existing, sections))
        print(f"[bench] wrote {DOC.relative_to(REPO)}")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
