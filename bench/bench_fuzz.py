"""The long fuzz run (`make fuzz`): every boundary's harness with far more cases than the
fixed-seed run in `make test`, and what each found.

1. Mutant corpora (``ether_ros.testing.mutants``, several seeds): the shipped configurations
   with every sampled key mutated, through ``load_bus_config`` and the simulator's slaves; the
   ESI files (project, corpus, shared vendor files read in place, the large ones too) through
   parser, layout, SII and the virtual slave. Counted: tracebacks, hangs, nonsense accepted,
   refusals that do not name the field.
2. proptest (cargo, release): frames and datagrams, the value codec, CDR and the resolver, the
   simulated ESC's register writes — ``FUZZ_CASES`` cases per property.
3. hypothesis (pytest): configuration values anywhere, ROS write requests, raw message bytes,
   joint commands and trajectories — ``FUZZ_EXAMPLES`` examples per property.

A run is repeatable: the seeds are fixed and printed. Nothing here is timed against a
baseline; the counts are the result (the time is given so a reader knows what was spent).
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
import time
from pathlib import Path

from ether_ros.testing import fuzzing, mutants
from report import Report

REPO = Path(__file__).resolve().parent.parent
CARGO_TESTS = [
    ("ether-ros-protocol", "fuzz_wire", "frames, datagrams, mailbox, addresses, values, bits"),
    ("ether-ros-commands", "fuzz_cdr", "CDR decoders and the native resolver"),
    ("ether-ros-sim", "fuzz_esc", "the simulated ESC's register and logical writes"),
]
HYPOTHESIS_TESTS = [
    ("tests/unit/test_fuzz_config.py::test_any_value_anywhere_is_taken_or_refused_cleanly",
     "configuration values anywhere"),
    ("tests/unit/test_fuzz_ros.py", "ROS write requests, raw bytes, joint commands, trajectories"),
]  # fmt: skip


def _corpus_row(name: str, outcomes: list[fuzzing.Outcome], seconds: float) -> list[object]:
    v = fuzzing.verdicts(outcomes)
    return [
        name,
        len(outcomes),
        v.counts.get("nonsense", 0),
        v.counts.get("refused", 0),
        v.counts.get("accepted", 0),
        len(v.tracebacks),
        len(v.hangs),
        len(v.nonsense_accepted),
        len(v.unnamed),
        f"{seconds:.0f}",
    ]


def _esi_taken(outcomes: list[fuzzing.Outcome], base: dict[str, str]) -> list[fuzzing.Outcome]:
    """Nonsense ESI mutants accepted silently with a parse that differs from the original's."""
    return [
        o
        for o in outcomes
        if o.mutant.nonsense
        and o.kind == "accepted"
        and o.detail.split()[1] == "0"
        and o.detail.split()[0] != base.get(o.mutant.name.split(":")[0])
    ]


def run(report: Report) -> None:
    quick = report.quick
    seeds = [1] if quick else [1, 2, 3]
    rows: list[list[object]] = []
    findings: list[str] = []

    for seed in seeds:
        corpus = mutants.config_mutants(seed=seed, leaves_per_file=8 if quick else 48)
        start = time.monotonic()
        outcomes = fuzzing.run_mutants(corpus, "ether_ros.testing.fuzzing:load_config")
        rows.append(_corpus_row(f"configs, seed {seed}", outcomes, time.monotonic() - start))
        v = fuzzing.verdicts(outcomes)
        findings += [f"config seed {seed}: {line}" for line in v.summary(5).splitlines()[1:]]

    target = "ether_ros.testing.fuzzing:load_esi_file"
    files = mutants.esi_files(max_bytes=500_000 if quick else None)
    originals = [mutants.Mutant(f.name, f.read_bytes()) for f in files]
    base = {
        o.mutant.name: o.detail.split()[0]
        for o in fuzzing.run_mutants(originals, target, suffix=".xml", timeout_s=120)
        if o.kind == "accepted"
    }
    for seed in seeds:
        corpus = mutants.esi_mutants(seed=seed, per_file=24 if quick else 64, files=files)
        start = time.monotonic()
        outcomes = fuzzing.run_mutants(corpus, target, suffix=".xml", timeout_s=120)
        v = fuzzing.verdicts(outcomes, lambda o: True)
        taken = _esi_taken(outcomes, base)
        row = _corpus_row(f"ESI files, seed {seed}", outcomes, time.monotonic() - start)
        row[7], row[8] = len(taken), "—"
        rows.append(row)
        findings += [f"ESI seed {seed}: {o.kind}: {o.mutant.name}" for o in v.tracebacks[:5]]
        findings += [f"ESI seed {seed}: taken: {o.mutant.name}" for o in taken[:5]]

    report.text(
        "### Mutant corpora\n\n"
        f"Configurations: `config/*.yaml`; ESI: {len(files)} files from `devices/`, "
        "`tests/data/esi` and the shared vendor files (read in place). A mutant is *nonsense* "
        "when no field can take its value; it must be refused naming its field (for ESI: "
        "refused, disabled with a warning, or ignored — never taken silently)."
    )
    report.table(
        ["corpus", "mutants", "nonsense", "refused", "accepted", "tracebacks", "hangs",
         "nonsense accepted", "refused without the field", "s"],
        rows,
    )  # fmt: skip
    report.value("corpora", rows)

    cases = 500 if quick else 20_000
    env = {**os.environ, "FUZZ_CASES": str(cases), "FUZZ_SEED": "7"}
    prop_rows = []
    for package, test, what in CARGO_TESTS:
        start = time.monotonic()
        proc = subprocess.run(
            ["cargo", "test", "--release", "-q", "-p", package, "--test", test],
            cwd=REPO, env=env, capture_output=True, text=True, check=False,
        )  # fmt: skip
        passed = re.search(r"(\d+) passed; (\d+) failed", proc.stdout)
        ok, failed = (int(passed.group(1)), int(passed.group(2))) if passed else (0, -1)
        prop_rows.append([f"`{test}`", what, ok + failed, cases, failed,
                          f"{time.monotonic() - start:.0f}"])  # fmt: skip
        if failed:
            found = re.findall(r"minimal failing input:.*", proc.stdout + proc.stderr)
            findings += [f"{test}: {f[:200]}" for f in found[:3]]
    examples = 300 if quick else 5_000
    env = {**os.environ, "FUZZ_EXAMPLES": str(examples)}
    for test, what in HYPOTHESIS_TESTS:
        start = time.monotonic()
        proc = subprocess.run(
            [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", test],
            cwd=REPO, env=env, capture_output=True, text=True, check=False,
        )  # fmt: skip
        counts = dict((k, int(n)) for n, k in re.findall(r"(\d+) (passed|failed)", proc.stdout))
        prop_rows.append([f"`{test.split('::')[0].rsplit('/', 1)[-1]}`", what,
                          counts.get("passed", 0) + counts.get("failed", 0), examples,
                          counts.get("failed", 0), f"{time.monotonic() - start:.0f}"])  # fmt: skip
        if counts.get("failed"):
            findings.append(f"{test}: {proc.stdout.strip().splitlines()[-1]}")
    report.text(
        "### Property fuzzing\n\n"
        f"proptest with `FUZZ_CASES={cases} FUZZ_SEED=7` (release build), hypothesis with "
        f"`FUZZ_EXAMPLES={examples}` (derandomized). `make test` runs the same properties with "
        "128–256 cases / 50–200 examples and seed 1 in seconds, and the config corpus of the two "
        "robot configurations (6 keys each)."
    )
    report.table(["harness", "what", "properties", "cases each", "failed", "s"], prop_rows)
    report.value("properties", prop_rows)
    report.text(
        "### Findings\n\n"
        + ("\n".join(f"- {f}" for f in findings) if findings else "None: every count above is 0.")
    )
