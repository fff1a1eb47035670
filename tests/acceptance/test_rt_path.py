"""The real-time path as it runs in production: ``ether-ros bench cycle`` against the simulator in
its own network namespace, with the engine's RT thread inspected from the outside.

- Syscalls: ``strace`` attached to the RT thread alone (found by its name ``ether_ros-rt`` in
  ``/proc/<pid>/task/*/comm``) sees only the cycle's own calls, never a lock (futex), memory
  management (mmap, brk, ...) or output.
- Setup: the thread runs SCHED_FIFO at the configured priority, pinned to the configured CPU, in a
  process whose memory is locked.
- The GIL: the loop keeps cycling, and records every cycle, while Python holds the GIL.

The allocation rule is audited in ``crates/engine/tests/rt_audit.rs``.
"""

from __future__ import annotations

import ctypes
import json
import shutil
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
import yaml

from ether_ros.sim.proof import SimProcess
from ether_ros.testing.netns import VethPair

pytestmark = pytest.mark.netns

REPO = Path(__file__).resolve().parents[2]
LAELAPS = REPO / "config" / "laelaps.yaml"
LINE128 = REPO / "config" / "line128.yaml"
RT_THREAD = "ether_ros-rt"

# What one cycle may ask of the kernel (crates/engine/src/cyclic.rs; crates/link/src: packet.rs,
# xdp.rs, clock.rs),
# per link:
COMMON_SYSCALLS = {
    "clock_nanosleep",  # sleep until the next cycle (absolute CLOCK_MONOTONIC)
    "ppoll",  # wait for a reply inside the cycle (cycle_order send_then_wait only)
    "clock_gettime",  # normally the vDSO (no syscall); a kernel without vDSO makes it one
    "restart_syscall",  # strace attaching interrupts the clock_nanosleep in progress
}
ALLOWED_SYSCALLS = {
    "packet": COMMON_SYSCALLS
    | {
        "sendto",  # the cyclic frame, and an acyclic frame from the mailbox (libc send = sendto)
        "recvmsg",  # replies, non-blocking, with the kernel receive timestamp
    },
    "xdp": COMMON_SYSCALLS
    | {
        "sendto",  # the TX kick: the frame is already on the TX ring (copy mode kicks each one)
        "recvfrom",  # the fill ring's wakeup kick, when the driver asks for one
    },
}
# Calls every traced window must contain (more than 10 each), per link: replies on the packet
# link are read with recvmsg; on the xdp link they are read from the RX ring without a syscall.
REQUIRED_SYSCALLS = {
    "packet": ("clock_nanosleep", "sendto", "recvmsg"),
    "xdp": ("clock_nanosleep", "sendto"),
}
SCHED_FIFO = 1


def rt_thread_of(proc: subprocess.Popen[str], timeout: float = 30.0) -> int:
    """The TID of the process's RT thread, once its loop is running."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            _out, err = proc.communicate()
            pytest.fail(f"bench ended before its RT thread ran (rc {proc.returncode}): {err}")
        for task in Path(f"/proc/{proc.pid}/task").iterdir():
            try:
                if (task / "comm").read_text().strip() == RT_THREAD:
                    return int(task.name)
            except OSError:
                continue  # the thread ended meanwhile
        time.sleep(0.01)
    pytest.fail(f"no thread named {RT_THREAD} in the bench process within {timeout} s")


def task_status(pid: int, tid: int) -> dict[str, str]:
    lines = Path(f"/proc/{pid}/task/{tid}/status").read_text().splitlines()
    return {k: v.strip() for k, _, v in (line.partition(":") for line in lines)}


def wait_for_cycles(pid: int, tid: int, switches: int = 100) -> None:
    """Wait until the thread is past its setup and in the loop: every cycle sleeps once, so
    voluntary context switches count cycles."""
    deadline = time.monotonic() + 30
    while int(task_status(pid, tid)["voluntary_ctxt_switches"]) < switches:
        assert time.monotonic() < deadline, "the RT thread does not cycle"
        time.sleep(0.01)


def sched_of(pid: int, tid: int) -> tuple[int, int]:
    """(rt_priority, policy) from /proc/<pid>/task/<tid>/stat (fields 40 and 41)."""
    stat = Path(f"/proc/{pid}/task/{tid}/stat").read_text()
    fields = stat[stat.rindex(")") + 2 :].split()  # fields from 3 (state) on
    return int(fields[40 - 3]), int(fields[41 - 3])


def strace_summary(stderr: str) -> dict[str, int]:
    """Syscall name -> calls from the table ``strace -c`` prints."""
    calls: dict[str, int] = {}
    rows = False
    for line in stderr.splitlines():
        if line.startswith("------"):
            rows = not rows
            continue
        parts = line.split()
        if rows and len(parts) >= 5 and parts[-1] != "total":
            calls[parts[-1]] = int(parts[3])
    return calls


@pytest.fixture
def sim(veth_ns: VethPair) -> Iterator[SimProcess]:
    with SimProcess(LAELAPS, veth_ns.slave, veth_ns.netns) as s:
        yield s


def config_with_order(order: str, tmp_path: Path) -> Path:
    """laelaps.yaml with another ``cycle_order`` (ESI directory made absolute)."""
    if order == "send_at_wake":
        return LAELAPS
    data = yaml.safe_load(LAELAPS.read_text())
    data["bus"]["cycle_order"] = order
    data["esi"] = [str(REPO / "devices")]
    path = tmp_path / f"laelaps_{order}.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


@pytest.mark.parametrize(
    ("bus", "order", "link"),
    [
        ("laelaps", "send_at_wake", "packet"),
        ("laelaps", "send_then_wait", "packet"),
        ("laelaps", "send_at_wake", "xdp"),
        ("laelaps", "send_then_wait", "xdp"),
        # 128 slaves: four cyclic frames per cycle, one sendto each.
        ("line128", "send_at_wake", "packet"),
    ],
)
def test_rt_thread_makes_only_the_cycles_syscalls_and_runs_as_configured(
    veth_ns: VethPair, tmp_path: Path, bus: str, order: str, link: str
) -> None:
    strace = shutil.which("strace")
    if strace is None:
        pytest.fail("strace is missing: scripts/bootstrap.sh installs it (APT_PACKAGES)")
    config = config_with_order(order, tmp_path) if bus == "laelaps" else LINE128
    with SimProcess(config, veth_ns.slave, veth_ns.netns):
        _trace_the_rt_thread(
            strace, config, veth_ns, tmp_path, frames=4 if bus == "line128" else 1, link=link
        )


def _trace_the_rt_thread(
    strace: str, config: Path, veth_ns: VethPair, tmp_path: Path, frames: int, link: str
) -> None:
    result = tmp_path / "bench.json"
    bench = subprocess.Popen(
        [sys.executable, "-m", "ether_ros.cli.main", "bench", "cycle",
         str(config), "--interface", veth_ns.master,
         "--cycle-us", "1000", "--seconds", "4", "--drift-frames", "300", "--json", str(result),
         "--link", link],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )  # fmt: skip
    try:
        tid = rt_thread_of(bench)
        wait_for_cycles(bench.pid, tid)

        # As configured in laelaps.yaml: realtime {policy: fifo, priority: 80, cpu: 1,
        # lock_memory: true}.
        assert sched_of(bench.pid, tid) == (80, SCHED_FIFO)
        assert task_status(bench.pid, tid)["Cpus_allowed_list"] == "1"
        vm_lck_kb = int(task_status(bench.pid, bench.pid)["VmLck"].split()[0])
        assert vm_lck_kb > 0, "lock_memory: true but nothing is locked (no mlockall)"

        tracer = subprocess.Popen(
            [strace, "-c", "-p", str(tid)],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        time.sleep(1.5)
        tracer.send_signal(signal.SIGINT)
        _out, traced = tracer.communicate(timeout=10)
        # The window must lie inside the loop, not in the shutdown (thread exit unmaps its
        # stack): the thread still cycles after the trace.
        still_cycling = (Path(f"/proc/{bench.pid}/task/{tid}")).exists()
    finally:
        out, err = bench.communicate(timeout=60)
    assert bench.returncode == 0, err
    assert still_cycling, "the trace overlapped the bench's shutdown: raise --seconds"
    calls = strace_summary(traced)
    for name in REQUIRED_SYSCALLS[link]:
        assert calls.get(name, 0) > 10, f"{name}: {traced}"
    # (send_then_wait calls ppoll only when the reply is not in yet: under strace, which slows
    # every syscall, it usually is, so ppoll is allowed but not required.)
    extra = set(calls) - ALLOWED_SYSCALLS[link]
    assert not extra, f"syscalls outside the cycle's own on {RT_THREAD}: {extra}\n{traced}"
    # Every cycle's timing is recorded: the bench reports the cycles it measured.
    measured = json.loads(result.read_text())
    assert measured["cycles"] > 0 and measured["period_us"]["p50"] is not None, out
    assert measured["frames"] == frames
    # One sendto per cyclic frame (plus the few acyclic frames of supervision).
    assert calls["sendto"] >= frames * calls["clock_nanosleep"] * 0.9, traced


def test_the_loop_cycles_and_records_while_python_holds_the_gil(
    sim: SimProcess, veth_ns: VethPair
) -> None:
    from ether_ros.config import load_bus_config
    from ether_ros.master import Bus

    cfg = load_bus_config(LAELAPS, interface=veth_ns.master)
    cfg.bus.cycle_us = 1000
    cfg.bus.realtime.cpu = None
    cfg.bus.realtime.lock_memory = False  # not for the whole pytest process
    cfg.bus.watchdog_ms = 0
    # A foreign function called through PyDLL keeps the GIL for its whole duration.
    usleep_holding_gil = ctypes.PyDLL(None).usleep
    usleep_holding_gil.argtypes = [ctypes.c_uint]
    with Bus.open(cfg, drift_frames=300) as bus:
        bus.start()
        bus.samples()
        t0 = time.monotonic_ns()
        usleep_holding_gil(500_000)
        t1 = time.monotonic_ns()
        time.sleep(0.05)
        samples = bus.samples()
        bus.stop()
    cycles = samples.records["cycle"]
    assert len(cycles) > 0
    # No cycle is missing from the record: consecutive cycle numbers, no overflow.
    assert np.all(np.diff(cycles.astype(np.int64)) == 1)
    woke = samples.records["t_wake_ns"]
    during = int(np.count_nonzero((woke > t0) & (woke < t1)))
    # 500 cycles are due in the window; a loop that needed the GIL would get at most one.
    assert during > 10, f"only {during} cycles while Python held the GIL for 0.5 s"
