"""Running mutants (:mod:`ether_ros.testing.mutants`) against a loader, with nothing able to
hang or exhaust the machine running them.

Each mutant is written to a file and handed to a *target* (a function ``path -> note``) in a
worker process whose address space is capped. The parent waits for each answer at most
``timeout_s``: a mutant that takes longer is a hang, its worker is killed and a new one goes on
with the next mutant. The outcome of each mutant is one of

- ``accepted``: the target returned;
- ``refused``: it raised the project's own error (:class:`ether_ros.errors.EtherRosError`); the
  error's text, type and ``field`` (when it has one) are kept;
- ``traceback``: it raised anything else (``MemoryError`` when it ran out of its address space);
- ``hang``: no answer within ``timeout_s``.

:func:`verdicts` checks the outcomes against the mutants' promises: 0 tracebacks, 0 hangs, and
every nonsense mutant refused naming its field.
"""

from __future__ import annotations

import collections
import importlib
import multiprocessing as mp
import os
import queue
import resource
import tempfile
import time
import traceback
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ether_ros.testing.mutants import Mutant

#: Address space of a worker: a loader that grows past this fails with MemoryError.
WORKER_MEMORY_BYTES = 3 * 1024**3


@dataclass(frozen=True)
class Outcome:
    mutant: Mutant
    kind: str  # accepted, refused, traceback, hang
    detail: str = ""
    field: str | None = None
    seconds: float = 0.0


def _worker(target: str, suffix: str, jobs: Any, results: Any, memory: int) -> None:
    """Run ``target`` (``module:function``) on each mutant received until None."""
    # Every mutant is a new file: the ESI disk cache would only fill up with them.
    from ether_ros.config.esi_cache import CACHE_SWITCH_ENV

    os.environ[CACHE_SWITCH_ENV] = "0"
    module, name = target.split(":")
    fn: Callable[[Path], Any] = getattr(importlib.import_module(module), name)
    from ether_ros.errors import EtherRosError

    if memory:  # after the imports, which map more than the mutants need
        resource.setrlimit(resource.RLIMIT_AS, (memory, memory))
    results.put(("ready",))

    with tempfile.TemporaryDirectory(prefix="ether_ros_fuzz_") as tmp:
        path = Path(tmp) / f"mutant{suffix}"
        while True:
            job = jobs.get()
            if job is None:
                return
            index, data = job
            path.write_bytes(data)
            start = time.perf_counter()
            try:
                note = fn(path)
                result = ("accepted", str(note or ""), None)
            except EtherRosError as exc:
                result = ("refused", f"{type(exc).__name__}: {exc}", getattr(exc, "field", None))
            except BaseException as exc:  # the finding: anything else is a traceback
                tb = traceback.format_exception(exc)
                result = ("traceback", "".join(tb[-3:]), None)
            results.put((index, *result, time.perf_counter() - start))


class _Worker:
    def __init__(self, target: str, suffix: str, memory: int) -> None:
        ctx = mp.get_context("spawn")
        self.jobs = ctx.Queue()
        self.results = ctx.Queue()
        self.process = ctx.Process(
            target=_worker,
            args=(target, suffix, self.jobs, self.results, memory),
            daemon=True,
        )
        self.process.start()

    def result(self, timeout_s: float) -> tuple[Any, ...] | None:
        """The worker's next answer; None when it gave none within ``timeout_s`` or died."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            try:
                return tuple(self.results.get(timeout=0.2))
            except queue.Empty:
                if not self.process.is_alive():
                    return None
        return None

    def stop(self, kill: bool = False) -> None:
        if kill:
            self.process.kill()
        else:
            self.jobs.put(None)
        self.process.join(timeout=10)
        if self.process.is_alive():
            self.process.kill()
            self.process.join()


def run_mutants(
    mutants: Sequence[Mutant],
    target: str,
    *,
    suffix: str = ".yaml",
    timeout_s: float = 20.0,
    memory: int = WORKER_MEMORY_BYTES,
    first_timeout_s: float = 120.0,
) -> list[Outcome]:
    """Run every mutant through ``target`` (``"module:function"``, called with the mutant's
    file path) in a worker process; a worker that does not answer within ``timeout_s`` is
    killed and the mutant counted as a hang (a worker starting up has ``first_timeout_s`` for
    its imports, which are not the mutant's)."""
    outcomes: list[Outcome] = []

    def start() -> _Worker:
        worker = _Worker(target, suffix, memory)
        if worker.result(first_timeout_s) != ("ready",):
            worker.stop(kill=True)
            raise RuntimeError(f"the fuzz worker for {target} did not start")
        return worker

    worker = start()
    try:
        for index, mutant in enumerate(mutants):
            worker.jobs.put((index, mutant.data))
            answer = worker.result(timeout_s)
            if answer is None:
                alive = worker.process.is_alive()
                worker.stop(kill=True)
                kind = "hang" if alive else "traceback"
                detail = "" if alive else f"worker died (exit code {worker.process.exitcode})"
                outcomes.append(Outcome(mutant, kind, detail, None, timeout_s))
                worker = start()
                continue
            _, kind, detail, field, seconds = answer
            outcomes.append(Outcome(mutant, kind, detail, field, seconds))
    finally:
        worker.stop()
    return outcomes


@dataclass(frozen=True)
class Verdict:
    """What a run of mutants found."""

    counts: dict[str, int]
    tracebacks: list[Outcome]
    hangs: list[Outcome]
    #: Nonsense mutants that were accepted.
    nonsense_accepted: list[Outcome]
    #: Nonsense mutants refused without naming their field.
    unnamed: list[Outcome]

    @property
    def clean(self) -> bool:
        return not (self.tracebacks or self.hangs or self.nonsense_accepted or self.unnamed)

    def summary(self, limit: int = 12) -> str:
        lines = [", ".join(f"{k} {v}" for k, v in sorted(self.counts.items()))]
        for label, items in (
            ("traceback", self.tracebacks),
            ("hang", self.hangs),
            ("nonsense accepted", self.nonsense_accepted),
            ("refused without naming the field", self.unnamed),
        ):
            for o in items[:limit]:
                lines.append(f"{label}: {o.mutant.name}: {o.detail.strip()[-400:]}")
        return "\n".join(lines)


def verdicts(
    outcomes: Sequence[Outcome], names_field: Callable[[Outcome], bool] | None = None
) -> Verdict:
    """Sort the outcomes by what they promise. ``names_field(outcome)`` decides whether a
    refused nonsense mutant named its field (default: the error's ``field`` is the mutant's
    key path, or the message holds it)."""
    check = names_field or _names_field
    counts = collections.Counter(o.kind for o in outcomes)
    counts["nonsense"] = sum(o.mutant.nonsense for o in outcomes)
    return Verdict(
        counts=dict(counts),
        tracebacks=[o for o in outcomes if o.kind == "traceback"],
        hangs=[o for o in outcomes if o.kind == "hang"],
        nonsense_accepted=[o for o in outcomes if o.mutant.nonsense and o.kind == "accepted"],
        unnamed=[o for o in outcomes if o.mutant.nonsense and o.kind == "refused" and not check(o)],
    )


def _names_field(o: Outcome) -> bool:
    """The refusal names the mutated field: the field itself, a value inside it (an error
    deeper in the path), or the list it is an item of (``position_limits`` for
    ``position_limits[1]``)."""
    field = o.mutant.field
    if field is None:
        return True
    named = o.field or ""
    return (
        named == field
        or named.startswith((field + ".", field + "["))
        or (bool(named) and field.startswith(named + "["))
    )


def cpu_count() -> int:
    return len(os.sched_getaffinity(0))


# ------------------------------------------------------------------------------------ targets
# What a mutant goes through: everything that reads a file of its kind, as a user's command
# would.


def load_config(path: Path) -> str:
    """A bus configuration as ``ether-ros sim`` reads it: the YAML, the ESI files it names,
    and the virtual slaves built from them."""
    from ether_ros.config import load_bus_config
    from ether_ros.sim.network import build_network

    cfg = load_bus_config(path)
    build_network(cfg)
    return f"{len(cfg.slaves)} slave(s)"


def load_esi_file(path: Path) -> str:
    """An ESI file as ``ether-ros sim --esi`` reads it: each device type (the first four)
    configured as a bus of one slave (process layout, SII image, read back) and built into a
    virtual slave. Returns ``DIGEST WARNINGS``: a digest of what was parsed and how many
    warnings the parser gave, so a caller can tell a value the parser ignored or disabled
    (same digest, or a warning) from one it took."""
    import hashlib

    from ether_ros.config import esi as esi_module
    from ether_ros.config import load_esi, parse_sii
    from ether_ros.config.from_esi import bus_config_for_esi
    from ether_ros.sim.network import build_network
    from ether_ros.sim.spec import network_specs

    devices = load_esi(path)
    load_file = getattr(esi_module, "load_esi_file", None)
    warnings = len(load_file(path).warnings) if load_file is not None else 0
    types = sorted({d.type_name for d in devices})
    for device in types[:4]:
        cfg = bus_config_for_esi(path, device)
        for spec in network_specs(cfg):
            parse_sii(spec.sii)
        build_network(cfg)
    digest = hashlib.sha256(repr(devices).replace(str(path), "ESI").encode()).hexdigest()[:16]
    return f"{digest} {warnings}"
