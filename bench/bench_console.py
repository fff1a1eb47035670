"""The panic key: from the key press on the operator's terminal to the safe outputs on the wire.

Setup: `RosRig` — the simulator (4 Laelaps II legs) and the node (`ether-ros run`, 400 µs cycle)
in their own processes on a veth pair. The operator tools run in their own processes on a
pseudo-terminal (`ether_ros.testing.pty`), as an operator runs them.

Each trial commands a new `Kp100_hip` of `front_left_leg` (unique in the run), waits until the
frames carry it, notes `time.time_ns()` and writes the panic key (Ctrl-P) into the terminal. A
raw socket on the simulator's end of the veth pair (`bench_ros.WireSniffer`) notes the kernel
timestamp (CLOCK_REALTIME, the clock of `time.time_ns()`) of the first frame whose LRW data
carries the safe value (0) there: key → wire. The node logs `PANIC: safe outputs on the wire`
right after it switched the engine to the safe outputs, with a wall-clock stamp; the tools note
when their native key reader sent the request (`ETHER_ROS_PANIC_TRACE`, CLOCK_MONOTONIC). That
splits key → wire into key → request sent (the tool's own share), sent → node (DDS, the node's
command executor) and node → wire (the engine's next frame). Then the panic is cleared and the
next trial begins. The states:

- **baseline**: the node's `panic` service called directly (rclpy, this process): the floor
  that any tool adds to;
- **console idle**: the console at its prompt;
- **console during `wait`**: the console running `wait 600` (the panic interrupts it);
- **console during a paste**: a 100 000-character paste written into the terminal, then the key
  right behind it (the console refuses the paste; the key has to get past what the terminal
  still holds of it);
- **top**: `ether-ros top` on the node's diagnostics.

The target (issue 19/21): panic on the wire within 50 ms of the key, in every state.
"""

from __future__ import annotations

import contextlib
import itertools
import os
import re
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from bench_ros import WireSniffer, _percentile, _variable_offset
from ether_ros.testing.wait import wait_for
from report import BenchSkipped, Report

REPO = Path(__file__).resolve().parent.parent
CONFIG = REPO / "config" / "laelaps.yaml"
SLAVE = "front_left_leg"  # the variable bench_ros's _variable_offset locates
VARIABLE = "Kp100_hip"
SAFE = 0  # Kp100_hip in the safe outputs
TARGET_MS = 50.0
PASTE = 100_000
MISS_S = 30.0  # a panic not on the wire by then is counted as missed
# Safe outputs that last this long are the panic's (the engine's watchdog lets go of them as soon
# as the node feeds it again, within a few cycles once it runs).
STAY_NS = 300_000_000
# The node's log line for a panic (rcutils format: [LEVEL] [sec.nsec] [node]: message).
PANIC_LOG = re.compile(r"\[ERROR\] \[(\d+)\.(\d{9})\] \[[^\]]*\]: PANIC: safe outputs")


class Trials:
    """Runs panic trials against the rig: key → wire and key → node latencies (ms)."""

    def __init__(self, rig: Any, sniffer: WireSniffer, trace: Path) -> None:
        self.rig = rig
        self.client = rig.client
        self.sniffer = sniffer
        self.trace = trace
        self.values = itertools.count(1001)
        self.to_node: dict[str, list[float]] = {}
        self.to_read: dict[str, list[float]] = {}  # key -> the reader's read returned
        self.to_sent: dict[str, list[float]] = {}  # key -> the request sent
        self.missed: dict[str, int] = {}
        self.disturbed: dict[str, int] = {}  # a watchdog trip came between key and panic
        self.screen: Callable[[], str] | None = None  # the tool's screen, shown for a miss

    def _on_wire(self, value: int) -> bool:
        changes = self.sniffer.changes
        return bool(changes) and changes[-1][1] == value

    def one(
        self,
        name: str,
        press: Callable[[], None],
        prepare: Callable[[], None] | None = None,
        after: Callable[[], None] | None = None,
    ) -> float | None:
        """Key → wire in ms; None (counted as missed) when the safe outputs do not reach the
        wire within MISS_S."""
        c = self.client
        ok, message = c.command("clear_panic")
        if not ok:
            raise RuntimeError(f"clear_panic: {message}")
        value = next(self.values)
        ok, message = c.write(SLAVE, VARIABLE, value)
        if not ok:
            raise RuntimeError(message)
        wait_for(f"{VARIABLE}={value} on the wire", lambda: self._on_wire(value))
        if prepare is not None:
            prepare()
        # The engine's own watchdog (bus.watchdog_ms) may have put the safe outputs on the wire
        # meanwhile (a node starved of CPU stops feeding it): the key must find the value.
        wait_for(f"{VARIABLE}={value} back on the wire", lambda: self._on_wire(value))
        seen = len(self.sniffer.changes)
        t_key_mono = time.monotonic_ns()
        t_key = time.time_ns()
        press()
        try:
            wait_for(
                "the safe outputs on the wire, to stay",
                lambda: self._safe_after(seen, t_key) is not None,
                MISS_S,
            )
        except AssertionError:
            self.missed.setdefault(name, 0)
            self.missed[name] += 1
            print(f"[bench console] {name}: no safe outputs on the wire within {MISS_S:g} s")
            print(f"  panic state reported by the node: {c.master_status().get('panic')}")
            print(f"  sniffer changes since the key: {self.sniffer.changes[seen:][-5:]}")
            with contextlib.suppress(OSError):
                print("  trace:", self.trace.read_text().splitlines()[-3:])
            print("  node log:", self.rig.node_log.read_text(errors="replace")[-800:])
            if self.screen is not None:
                print("  screen:", self.screen()[-1500:])
            if after is not None:
                with contextlib.suppress(AssertionError):
                    after()
            return None
        stamp = self._safe_after(seen, t_key)
        assert stamp is not None
        if any(v == value for _t, v in self.sniffer.changes[seen:]):
            # The value came back after a safe frame: a watchdog trip came between.
            self.disturbed[name] = self.disturbed.get(name, 0) + 1
        logged = self._logged(t_key)
        if logged is not None:
            self.to_node.setdefault(name, []).append((logged - t_key) / 1e6)
        sent = self._sent(t_key_mono) if not name.startswith("baseline") else None
        if sent is not None:
            self.to_read.setdefault(name, []).append((sent[0] - t_key_mono) / 1e6)
            self.to_sent.setdefault(name, []).append((sent[1] - t_key_mono) / 1e6)
        if after is not None:
            after()
        return (stamp - t_key) / 1e6

    def _safe_after(self, start: int, t_key: int) -> int | None:
        """The kernel stamp of the frame that began the safe outputs that stay (a panic holds
        them until it is cleared; a watchdog trip ends at the next write): the last change,
        when it is to the safe value, after the key, and has lasted STAY_NS."""
        changes = self.sniffer.changes[start:]
        if not changes:
            return None
        stamp, value = changes[-1]
        if value == SAFE and stamp >= t_key and time.time_ns() - stamp >= STAY_NS:
            return stamp
        return None

    def _sent(self, t_key: int) -> tuple[int, int] | None:
        """When the tool's native key reader got the key and sent the request (its trace),
        after ``t_key``."""
        deadline = time.monotonic() + 2.0
        while time.monotonic() < deadline:
            with contextlib.suppress(OSError):
                for line in self.trace.read_text().splitlines():
                    read_ns, sent_ns = (int(x) for x in line.split())
                    if read_ns >= t_key:
                        return read_ns, sent_ns
            time.sleep(0.01)
        return None

    def _logged(self, t_key: int) -> int | None:
        """The stamp of the node's first panic log line after ``t_key`` (it may come a little
        after the frame; None if it does not come within 2 s)."""
        deadline = time.monotonic() + 2.0
        while time.monotonic() < deadline:
            text = self.rig.node_log.read_text(errors="replace")
            for m in PANIC_LOG.finditer(text):
                stamp = int(m.group(1)) * 1_000_000_000 + int(m.group(2))
                if stamp >= t_key:
                    return stamp
            time.sleep(0.01)
        return None


def run(report: Report) -> None:
    if os.geteuid() != 0:
        raise BenchSkipped("needs root (veth pairs)")
    from ether_ros.ros.rig import RosRig
    from ether_ros.testing.pty import CTRL_P, Pty

    n = 5 if report.quick else 25
    results: dict[str, list[float]] = {}
    load: list[float] = []
    with RosRig(CONFIG) as rig, contextlib.ExitStack() as stack:
        client = rig.client
        client.wait_for_node()
        client.layout(timeout=10)
        assert rig.veth is not None
        sniffer = WireSniffer(rig.veth.slave, _variable_offset())
        stack.callback(sniffer.close)
        trace = rig.dir / "panic_trace"
        trials = Trials(rig, sniffer, trace)
        env = dict(rig.env, PROMPT_TOOLKIT_NO_CPR="1", ETHER_ROS_PANIC_TRACE=str(trace))
        cli = [sys.executable, "-m", "ether_ros.cli.main"]

        console = stack.enter_context(Pty([*cli, "console"], env=env))
        console.expect("ether_ros>", timeout=60)
        top = stack.enter_context(Pty([*cli, "top"], env=env))
        top.expect("OP", timeout=60)
        time.sleep(1.0)  # the screens settled

        def key() -> None:
            console.write(CTRL_P)

        marks: list[int] = []

        def start_wait() -> None:
            marks.append(console.mark())
            console.write(b"wait 600\r")
            console.expect(r"\[running: wait 600", since=marks[-1])

        def wait_interrupted() -> None:  # the console is idle again before the next trial
            console.expect(r"interrupted \(panic\)", since=marks[-1])

        paste = b"set all b_ellipse100=4 " + b"x" * PASTE

        def paste_then_key() -> None:
            console.write(paste)  # returns once the terminal took the last byte of it
            console.write(CTRL_P)

        def end_refused_line() -> None:  # its Enter ends the refused paste's line
            console.write(b"\r")

        states: list[tuple[str, Callable[[], None], Any, Any]] = [
            ("baseline: the panic service called directly", lambda: client.panic(), None, None),
            ("console idle (at its prompt)", key, None, None),
            ("console during `wait 600`", key, start_wait, wait_interrupted),
            ("console during a 100k-character paste", paste_then_key, None, end_refused_line),
            ("top (node mode)", lambda: top.write(CTRL_P), None, None),
        ]
        load.append(os.getloadavg()[0])
        # Round by round, one trial of each state: every state sees the same load on the
        # (shared) machine.
        for _ in range(n):
            for name, press, prepare, after in states:
                trials.screen = top.text if name.startswith("top") else console.text
                latency = trials.one(name, press, prepare, after)
                results.setdefault(name, [])
                if latency is not None:
                    results[name].append(latency)
        load.append(os.getloadavg()[0])
        client.command("clear_panic")
        console.write(b"quit\r")
        console.wait(30)

    base = _percentile(results["baseline: the panic service called directly"], 0.5)
    rows = []
    for name, values in results.items():
        if not values:
            values = [float("nan")]  # every trial missed
        p50, p99, top_ms = _percentile(values, 0.5), _percentile(values, 0.99), max(values)
        within = sum(v <= TARGET_MS for v in values)
        missed = trials.missed.get(name, 0)
        node = trials.to_node.get(name, [])
        sent = trials.to_sent.get(name, [])
        read = trials.to_read.get(name, [])
        rows.append(
            [
                name,
                len(values),
                f"{p50:.1f} / {p99:.1f} / {top_ms:.1f}",
                f"{p50 / base:.1f}×",
                f"{within}/{len(values) + missed}",
                str(missed),
                f"{_percentile(read, 0.5):.2f} / {max(read):.2f}" if read else "-",
                f"{_percentile(sent, 0.5):.2f} / {max(sent):.2f}" if sent else "-",
                f"{_percentile(node, 0.5):.1f} / {max(node):.1f}" if node else "-",
            ]
        )
        key_name = re.sub(r"\W+", "_", name.split(":")[0].split(" (")[0]).strip("_")
        report.value(f"{key_name}_p50_ms", p50)
        report.value(f"{key_name}_p99_ms", p99)
        report.value(f"{key_name}_max_ms", top_ms)
        report.value(f"{key_name}_within_target", within)
        report.value(f"{key_name}_missed", missed)
    report.text(
        "Key press in the terminal (or the service call, for the baseline) → first frame "
        "carrying the safe outputs at the simulator's end of the veth pair (kernel timestamp); "
        "key → read: the terminal delivers the key to the tool's native key reader (the kernel's "
        "tty layer and the thread's wake-up); key → request sent: the reader has sent the "
        "request; key → node: "
        "to the node's log line written right after it switched to the safe outputs. "
        f"Target: {TARGET_MS:g} ms in every state."
    )
    report.table(
        [
            "state",
            "trials",
            "key → wire ms p50 / p99 / max",
            "p50 vs baseline",
            f"within {TARGET_MS:g} ms",
            f"missed (none in {MISS_S:g} s)",
            "key → read by the tool ms p50 / max",
            "key → request sent ms p50 / max",
            "key → node ms p50 / max",
        ],
        rows,
    )
    report.value("load_average", load)
    # The tools' own work per trial: from the read that held the key to the request sent.
    own = [
        sent - read
        for name in trials.to_sent
        for read, sent in zip(trials.to_read[name], trials.to_sent[name], strict=True)
    ]
    if own:
        report.value("read_to_sent_p50_ms", _percentile(own, 0.5))
        report.value("read_to_sent_max_ms", max(own))
        report.text(
            f"The tools' own share — from the read that held the key to the request sent — "
            f"is {_percentile(own, 0.5):.2f} ms at p50 and {max(own):.2f} ms at most over "
            f"all {len(own)} trials. The tail of key → wire lies before it (key → read: the "
            "kernel's tty layer passes the key on from a worker thread, which waits for a CPU on "
            "a loaded machine) or after it (sent → node: the node's Python command executor)."
        )
    worst = max(max(v) for v in results.values() if v)
    if trials.disturbed:
        report.text(
            "The engine's watchdog put the safe outputs on the wire on its own (the node, "
            "starved of CPU, did not feed it for `bus.watchdog_ms`) between the key and the "
            f"panic in {sum(trials.disturbed.values())} trial(s) "
            f"({', '.join(f'{k}: {v}' for k, v in trials.disturbed.items())}); those count "
            "from the key to the start of the safe outputs that stayed."
        )
    if trials.missed:
        report.text(
            f"**Missed**: {sum(trials.missed.values())} trial(s) saw no safe outputs on the wire "
            f"within {MISS_S:g} s ({', '.join(f'{k}: {v}' for k, v in trials.missed.items())})."
        )
    report.text(
        f"Load average of the machine (1 min) at the start and the end: {load[0]:.1f}, "
        f"{load[1]:.1f} ({os.cpu_count()} CPUs); the trials ran round by round, one of each "
        "state per round."
    )
    report.text(
        f"Worst case over all states: {worst:.1f} ms "
        + ("(within the target)." if worst <= TARGET_MS else f"(**beyond {TARGET_MS:g} ms**).")
    )
