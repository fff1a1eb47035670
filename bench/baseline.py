"""Same-machine baselines for the benchmarks: scheduling latency (cyclictest) and the round trip
of a minimal C EtherCAT echo over a veth pair, measured by a C probe.

Everything timing-critical runs in C (``bench/c``), built here with ``cc -O2`` into
``bench/.build``; Python only starts processes and parses their output. Processes are started
with argument lists, never through a shell.
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from report import BenchSkipped

BENCH = Path(__file__).resolve().parent
C_DIR = BENCH / "c"
BUILD = BENCH / ".build"


class ToolError(RuntimeError):
    """A benchmark tool could not be built or did not produce the expected output."""


def build_c_tool(name: str) -> Path:
    """Compile ``bench/c/<name>.c`` (rebuilt when a source is newer) and return the binary."""
    src = C_DIR / f"{name}.c"
    out = BUILD / name
    sources = [src, *C_DIR.glob("*.h")]
    if out.exists() and all(out.stat().st_mtime >= s.stat().st_mtime for s in sources):
        return out
    cc = shutil.which("cc") or shutil.which("gcc")
    if cc is None:
        raise ToolError("no C compiler (cc) found")
    BUILD.mkdir(exist_ok=True)
    result = subprocess.run(
        [cc, "-O2", "-Wall", "-Wextra", "-o", str(out), str(src)],
        capture_output=True,
        text=True,
        check=False,
    )
    if result.returncode != 0:
        raise ToolError(f"building {src.name} failed:\n{result.stderr}")
    return out


# ---------------------------------------------------------------------------------------------
# cyclictest


@dataclass
class LatencyHistogram:
    """A latency histogram in 1 µs buckets (cyclictest ``-h``), all threads summed."""

    counts: list[int]
    overflows: int
    min_us: int
    max_us: int
    avg_us: int

    @property
    def total(self) -> int:
        return sum(self.counts) + self.overflows

    def percentile(self, p: float) -> int:
        """The latency (µs) at or below which ``p`` % of the samples fall; beyond the histogram
        range (an overflow) the reported maximum is returned."""
        total = self.total
        if total == 0:
            return 0
        need = p / 100.0 * total
        seen = 0
        for us, count in enumerate(self.counts):
            seen += count
            if seen >= need:
                return us
        return self.max_us


def parse_cyclictest(output: str) -> LatencyHistogram:
    """Parse ``cyclictest -q -h N`` output: bucket lines ``US COUNT [COUNT ...]`` and the
    ``# Min/Avg/Max Latencies`` and ``# Histogram Overflows`` summary lines."""
    buckets: dict[int, int] = {}
    summary: dict[str, list[int]] = {}
    for line in output.splitlines():
        line = line.strip()
        if not line:
            continue
        if line.startswith("#"):
            key, _, rest = line[1:].partition(":")
            nums = [int(x) for x in rest.split() if x.isdigit()]
            if nums:
                summary[key.strip()] = nums
            continue
        fields = line.split()
        if all(f.isdigit() for f in fields) and len(fields) >= 2:
            buckets[int(fields[0])] = sum(int(f) for f in fields[1:])
    if "Max Latencies" not in summary:
        raise ToolError("cyclictest output has no '# Max Latencies' line:\n" + output[-500:])
    size = max(buckets) + 1 if buckets else 0
    counts = [buckets.get(i, 0) for i in range(size)]
    return LatencyHistogram(
        counts=counts,
        overflows=sum(summary.get("Histogram Overflows", [0])),
        min_us=min(summary.get("Min Latencies", [0])),
        max_us=max(summary["Max Latencies"]),
        avg_us=max(summary.get("Avg Latencies", [0])),
    )


def cyclictest(
    interval_us: int, seconds: float, priority: int = 80, max_us: int = 1000
) -> LatencyHistogram:
    """Run cyclictest (memory locked, SCHED_FIFO ``priority``, one thread) and return its
    wake-up latency histogram."""
    exe = shutil.which("cyclictest")
    if exe is None:
        raise ToolError("cyclictest not found (package rt-tests)")
    cmd = [
        exe, "-m", "-p", str(priority), "-i", str(interval_us),
        "-D", f"{max(1, round(seconds))}s", "-q", "-h", str(max_us),
    ]  # fmt: skip
    result = subprocess.run(cmd, capture_output=True, text=True, check=False)
    if result.returncode != 0:
        raise ToolError(f"cyclictest failed ({result.returncode}): {result.stderr.strip()}")
    return parse_cyclictest(result.stdout)


# ---------------------------------------------------------------------------------------------
# C echo and round-trip probe


@dataclass
class RttResult:
    """What ``bench/c/rtt.c`` prints, as numbers (round trips in ns)."""

    sent: int
    answered: int
    lost: int
    late_sends: int
    rate_hz: float
    elapsed_s: float
    rtt_ns: dict[str, float]
    # Answered, but later than the probe's -l threshold (0 when none was given).
    over: int = 0

    @classmethod
    def parse(cls, output: str) -> RttResult:
        try:
            d: dict[str, Any] = json.loads(output.strip().splitlines()[-1])
            return cls(
                sent=int(d["sent"]),
                answered=int(d["answered"]),
                lost=int(d["lost"]),
                late_sends=int(d["late_sends"]),
                rate_hz=float(d["rate_hz"]),
                elapsed_s=float(d["elapsed_s"]),
                rtt_ns={k: float(v) for k, v in d["rtt_ns"].items()},
                over=int(d.get("over", 0)),
            )
        except (ValueError, KeyError, IndexError) as e:
            raise ToolError(f"unexpected rtt output ({e}): {output[-300:]!r}") from e


def netns_prefix(netns: str | None) -> list[str]:
    """Command prefix that runs a program inside network namespace ``netns`` (if any)."""
    return ["ip", "netns", "exec", netns] if netns else []


@contextmanager
def echo_responder(
    interface: str, netns: str | None = None, priority: int = 0, cpu: int | None = None
) -> Iterator[subprocess.Popen[str]]:
    """Run the C echo on ``interface`` (optionally in ``netns``) for the duration of the block."""
    exe = build_c_tool("echo")
    cmd = [*netns_prefix(netns), str(exe), interface, "-p", str(priority)]
    if cpu is not None:
        cmd += ["-c", str(cpu)]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert proc.stdout is not None
        line = proc.stdout.readline()
        if line.strip() != "ready":
            err = proc.stderr.read() if proc.stderr else ""
            raise ToolError(f"echo did not start on {interface}: {line!r} {err}")
        yield proc
    finally:
        proc.terminate()
        try:
            proc.wait(timeout=5)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


def rtt_probe(
    interface: str,
    *,
    rate_hz: float = 0.0,
    frames: int = 2000,
    seconds: float | None = None,
    lrw_bytes: int = 240,
    warmup: int = 100,
    timeout_us: int = 100_000,
    priority: int = 0,
    cpu: int | None = None,
    netns: str | None = None,
    over_us: int | None = None,
) -> RttResult:
    """Send LRW frames out of ``interface`` and measure the answers (see bench/c/rtt.c).

    ``rate_hz`` 0: ping-pong (next frame after the answer); otherwise paced at that rate for
    ``seconds`` (or ``frames`` frames)."""
    exe = build_c_tool("rtt")
    cmd = [
        *netns_prefix(netns), str(exe), interface,
        "-r", str(rate_hz), "-s", str(lrw_bytes), "-w", str(warmup),
        "-t", str(timeout_us), "-p", str(priority),
    ]  # fmt: skip
    if seconds is not None and rate_hz > 0:
        cmd += ["-d", str(seconds)]
    else:
        cmd += ["-n", str(frames)]
    if cpu is not None:
        cmd += ["-c", str(cpu)]
    if over_us is not None:
        cmd += ["-l", str(over_us)]
    result = subprocess.run(cmd, capture_output=True, text=True, check=False, timeout=600)
    if result.returncode != 0:
        raise ToolError(f"rtt failed ({result.returncode}): {result.stderr.strip()}")
    return RttResult.parse(result.stdout)


# ---------------------------------------------------------------------------------------------
# CPU use of another process


def process_cpu_seconds(pid: int) -> float:
    """User + system CPU time (s) of a process so far, all its threads, from /proc."""
    return sum(thread_cpu_seconds(pid).values())


def thread_cpu_seconds(pid: int) -> dict[str, float]:
    """User + system CPU time (s) per thread of a process: ``{"<tid> <name>": seconds}``."""
    tick = float(_clock_ticks())
    out: dict[str, float] = {}
    for task in Path(f"/proc/{pid}/task").iterdir():
        try:
            stat = (task / "stat").read_text()
        except OSError:
            continue  # the thread ended meanwhile
        # The name is in parentheses and may contain spaces; the fields after it are fixed.
        name = stat[stat.index("(") + 1 : stat.rindex(")")]
        fields = stat[stat.rindex(")") + 2 :].split()
        utime, stime = int(fields[11]), int(fields[12])
        out[f"{task.name} {name}"] = (utime + stime) / tick
    return out


def _clock_ticks() -> int:
    import os

    return os.sysconf("SC_CLK_TCK")


@dataclass
class CpuSample:
    """CPU seconds per thread at one instant, to difference over a measurement window."""

    wall: float
    threads: dict[str, float]

    @classmethod
    def take(cls, pid: int) -> CpuSample:
        return cls(time.monotonic(), thread_cpu_seconds(pid))

    def share_since(self, earlier: CpuSample) -> tuple[float, str, float]:
        """(whole-process share of one core, busiest thread, its share) since ``earlier``."""
        wall = max(self.wall - earlier.wall, 1e-9)
        total = 0.0
        busiest, busiest_share = "", 0.0
        for name, secs in self.threads.items():
            share = (secs - earlier.threads.get(name, 0.0)) / wall
            total += share
            if share > busiest_share:
                busiest, busiest_share = name, share
        return total, busiest, busiest_share


def ether_ros_exe() -> str:
    """The `ether-ros` command of this venv (or on PATH)."""
    exe = Path(sys.executable).parent / "ether-ros"
    if exe.exists():
        return str(exe)
    found = shutil.which("ether-ros")
    if found is None:
        raise BenchSkipped("the ether-ros command is not installed (make build)")
    return found


@contextmanager
def simulator(
    config: Path, interface: str, netns: str | None, cpu: int | None = None, link: str = "packet"
) -> Iterator[subprocess.Popen[str]]:
    """`ether-ros sim CONFIG` on ``interface`` (in ``netns``) until the block ends; with ``cpu``,
    all its threads are pinned to that CPU (taskset); ``link`` is its ``--link``."""
    taskset = shutil.which("taskset") if cpu is not None else None
    pin = [taskset, "-c", str(cpu)] if taskset else []
    cmd = [
        *netns_prefix(netns), *pin, ether_ros_exe(), "sim", str(config),
        "--interface", interface, "--no-control", "--link", link,
    ]  # fmt: skip
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        first: list[str] = []
        ready = threading.Event()

        def wait_ready() -> None:
            assert proc.stdout is not None
            first.append(proc.stdout.readline())
            ready.set()

        threading.Thread(target=wait_ready, daemon=True).start()
        if not ready.wait(60) or "ready" not in first[0]:
            proc.kill()
            err = proc.stderr.read() if proc.stderr else ""
            raise ToolError(f"the simulator did not start: {first[:1]} {err.strip()[-800:]}")
        yield proc
    finally:
        if proc.poll() is None:
            proc.terminate()
            try:
                proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
        for stream in (proc.stdout, proc.stderr):
            if stream is not None:
                stream.close()


def parse_worker_args(mode: str, argv: list[str] | None) -> argparse.Namespace:
    """What ``run_worker`` passes a worker: MODE CONFIG INTERFACE CYCLE_US SECONDS OUT."""
    parser = argparse.ArgumentParser(description=f"{mode} worker of a benchmark (internal)")
    sub = parser.add_subparsers(dest="cmd", required=True)
    p = sub.add_parser(mode)
    p.add_argument("config", type=Path)
    p.add_argument("interface")
    p.add_argument("cycle_us", type=int)
    p.add_argument("seconds", type=float)
    p.add_argument("out", type=Path)
    return parser.parse_args(argv)


def run_worker(script: Path, mode: str, args: list[str], timeout: float) -> dict[str, Any]:
    """Run ``script mode *args OUT`` in its own process (a fresh interpreter, so its scheduling
    and memory locking stay its own) and return the JSON it wrote to OUT."""
    with tempfile.TemporaryDirectory(prefix=f"bench_{mode}_") as tmp:
        out = Path(tmp) / f"{mode}.json"
        cmd = [sys.executable, str(script), mode, *args, str(out)]
        try:
            r = subprocess.run(cmd, capture_output=True, text=True, check=False, timeout=timeout)
        except subprocess.TimeoutExpired as e:
            raise ToolError(f"the {mode} worker hung") from e
        if r.returncode != 0 or not out.exists():
            detail = (r.stderr.strip() or r.stdout.strip())[-800:]
            raise ToolError(f"the {mode} worker failed ({r.returncode}): {detail}")
        result: dict[str, Any] = json.loads(out.read_text())
        return result


def one_lrw_plan(
    *,
    cycle_us: int,
    order: str,
    image: bytes,
    output_bytes: int,
    sync0_shift_ns: int,
    priority: int,
    axes: Sequence[Any] = (),
) -> Any:
    """The engine plan (``_native.Plan``) of the benchmarks' synthetic bus: DC write + sync to
    station 0x1001 and one LRW of ``image`` (outputs first), no watchdog, a large sample ring;
    ``axes``: ``_native.AxisPlan``s."""
    from ether_ros import _native

    station = 0x1001
    datagrams = [
        _native.DcDatagram(kind="dc_write_ref", station=station),
        _native.DcDatagram(kind="dc_sync", station=station),
        _native.LogicalDatagram(
            kind="lrw", address=0x10000, length=len(image), image_offset=0, expected_wkc=0
        ),
    ]
    return _native.Plan(
        cycle_ns=cycle_us * 1000,
        order=order,
        frames=[_native.Frame(datagrams=datagrams, every=1, watchdog_ns=0)],
        image_len=len(image),
        output_ranges=[(0, output_bytes)],
        initial_image=image,
        safe_image=image,
        dc=_native.DcSettings(
            mode="ref_follows_master", time_offset_ns=0, sync0_shift_ns=sync0_shift_ns
        ),
        rt=_native.RtSettings(
            policy="fifo", priority=priority, cpu=None, runtime_ns=0, lock_memory=True
        ),
        watchdog_ns=0,
        ring_capacity=65536,
        axes=list(axes),
    )
