"""The operator console: a prompt_toolkit REPL that operates a running ether_ros node over ROS 2.

Every line goes through :func:`ether_ros.console.commands.parse_command` first; an invalid line
gets its reason and nothing is sent. Panic is one key away: Ctrl-P or F1 call the node's
``panic`` service at once, whatever is typed on the line (and ``panic`` works as a command).
Sequence files run step by step (``run FILE [step]``); Ctrl-C stops a running sequence.
"""

from __future__ import annotations

import contextlib
import time
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import Any

from ether_ros.console.commands import (
    AxisOp,
    Command,
    CommandError,
    ConsoleContext,
    Control,
    Get,
    Help,
    JointLimits,
    LeaseOp,
    Move,
    Quit,
    RunSequence,
    SdoRead,
    SdoWrite,
    SetMode,
    Show,
    Wait,
    Write,
    help_text,
    parse_command,
)
from ether_ros.console.sequence import load_sequence
from ether_ros.errors import EtherRosError
from ether_ros.ros.client import EtherRosClient, make_write
from ether_ros.ros.values import format_value

HISTORY_FILE = Path.home() / ".ether_ros_console_history"
PANIC_KEYS = ("c-p", "f1")
SENT_MEMORY_S = 2.0
# How long a move waits for the node to refuse it (it answers only refusals).
MOVE_ANSWER_S = 0.3


class QuitConsole(Exception):
    pass


class Console:
    """Executes parsed commands against the node; prints through ``out``."""

    def __init__(
        self,
        client: EtherRosClient,
        out: Callable[[str], None] = print,
        confirm: Callable[[str], str] | None = None,
    ) -> None:
        self.client = client
        self.out = out
        self.confirm = confirm or (lambda prompt: input(prompt))
        # What this console wrote recently, until the node's snapshots (pdo_out_timer, every
        # ros.snapshot_period_ms) have surely caught up: the next command is checked against
        # the values just sent, not against a snapshot from before them.
        self._sent: dict[tuple[str, str], tuple[float, float]] = {}
        self._axes: dict[str, JointLimits] | None = None  # from the node's parameters, once

    def context(self) -> ConsoleContext:
        """The layout and the last commanded outputs (``pdo_out_timer``; the wire echo when no
        snapshot arrived yet), for checking writes."""
        latest = self.client.latest
        outputs = {slave: dict(values) for slave, values in latest.outputs.items()}
        for slave, values in latest.commanded.items():
            outputs[slave] = dict(values)
        now = time.monotonic()
        for (slave, variable), (value, sent_at) in list(self._sent.items()):
            if now - sent_at > SENT_MEMORY_S:
                del self._sent[(slave, variable)]
            else:
                outputs.setdefault(slave, {})[variable] = value
        return ConsoleContext(latest.layout, outputs, self._joints())

    def _joints(self) -> dict[str, JointLimits]:
        """The axes with their limits (the node's ``axes.*`` parameters, read once) and each
        one's mode as the diagnostics last reported it."""
        if self._axes is None:  # not read yet (a bus without axes: {})
            try:
                params = self.client.axis_parameters()
                self._axes = {
                    name: JointLimits(
                        str(p["mode"]), p["position_limits"], p["velocity_limit"], p["torque_limit"]
                    )
                    for name, p in params.items()
                }
            except EtherRosError:
                return {}
        reported = self.client.axis_states()
        return {
            name: replace(limits, mode=reported.get(name, {}).get("mode", limits.mode))
            for name, limits in self._axes.items()
        }

    def line(self, text: str) -> bool:
        """Parse and run one line; False when the console should end."""
        try:
            command = parse_command(text, self.context())
            if command is not None:
                self.execute(command)
        except QuitConsole:
            return False
        except EtherRosError as exc:
            self.out(f"error: {exc}")
        return True

    def panic(self) -> None:
        try:
            ok, message = self.client.panic()
        except EtherRosError as exc:
            ok, message = False, str(exc)
        self.out(("PANIC: " if ok else "panic FAILED: ") + message)

    def execute(self, command: Command) -> bool:
        """Run one command; False when the node refused it (the reason is printed)."""
        ok, message = True, ""
        if isinstance(command, Control):
            if command.command == "panic":
                ok, message = self.client.panic()
                message = ("PANIC: " if ok else "") + message
            else:
                ok, message = self.client.command(command.command)
        elif isinstance(command, Write):
            writes = [make_write(op.slave, op.variable, op.value) for op in command.ops]
            ok, message = self.client.write_many(writes)
            if ok:
                now = time.monotonic()
                for op in command.ops:
                    self._sent[(op.slave, op.variable)] = (op.value, now)
        elif isinstance(command, Get):
            self._get(command)
        elif isinstance(command, Show):
            self._show(command)
        elif isinstance(command, SdoRead):
            r = self.client.sdo_read(command.slave, command.index, command.subindex, command.type)
            ok, message = bool(r.success), str(r.message)
        elif isinstance(command, SdoWrite):
            ok, message = self.client.sdo_write(
                command.slave, command.index, command.subindex, command.type, command.value
            )
        elif isinstance(command, RunSequence):
            ok = self.run_sequence(command.path, command.step)
        elif isinstance(command, Wait):
            time.sleep(command.seconds)
        elif isinstance(command, AxisOp):
            ok, message, _ = self.client.axis_command(command.command, list(command.joints))
        elif isinstance(command, SetMode):
            ok, message, _ = self.client.set_mode(command.mode, list(command.joints))
        elif isinstance(command, Move):
            ok, message = self._move(command)
        elif isinstance(command, LeaseOp):
            ok, message = self._lease(command.action)
        elif isinstance(command, Help):
            message = help_text(command.topic)
        elif isinstance(command, Quit):
            raise QuitConsole
        if message:
            self.out(message if ok else f"error: {message}")
        return ok

    def _lease(self, action: str) -> tuple[bool, str]:
        """``lease``: who holds it; ``lease take``: take it over (this console commands from
        now on); ``lease release``: give it back (the outputs stay as they are)."""
        if action == "take":
            return self.client.acquire_lease(takeover=True)
        if action == "release":
            return self.client.release_lease()
        st = self.client.lease_status()
        if not st.enabled:
            return True, str(st.message)
        mine = " (this console)" if self.client.lease_token else ""
        return True, f"{st.message}{mine}"

    def _move(self, command: Move) -> tuple[bool, str]:
        before = len(self.client.joint_results)
        self.client.publish_joint_command([command.joint], **{command.array: [command.value]})
        try:  # the node answers refusals only
            self.client.wait_for(lambda _l: len(self.client.joint_results) > before, MOVE_ANSWER_S)
        except EtherRosError:
            return True, f"sent {command.joint} {command.array}={command.value:g}"
        result = self.client.joint_results[before]
        return bool(result.success), str(result.message)

    def _get(self, command: Get) -> None:
        latest = self.client.latest
        groups = (
            ("inputs", latest.inputs.get(command.slave, {})),
            ("outputs (on the wire)", latest.outputs.get(command.slave, {})),
        )
        if command.variable is not None:
            for label, values in groups:
                if command.variable in values:
                    self.out(f"{command.slave}.{command.variable} = {values[command.variable]:g}")
                    self.out(f"  ({label})")
                    return
            self.out(f"no value of {command.variable} received yet")
            return
        for label, values in groups:
            self.out(f"{command.slave} {label}:")
            if not values:
                self.out("  (nothing received yet)")
            for name, value in values.items():
                self.out(f"  {name:24} {value:g}")

    def _show(self, command: Show) -> None:
        if command.what == "states":
            with contextlib.suppress(EtherRosError):
                self.client.wait_for(lambda latest: latest.diagnostics, timeout=2.5)
            try:
                state = self.client.get_state()
            except EtherRosError as exc:
                state = f"unknown ({exc})"
            self.out(f"node {self.client.target}: {state}")
            for slave, al in self.client.slave_states().items():
                self.out(f"  {slave:24} {al}")
        elif command.what == "stats":
            with contextlib.suppress(EtherRosError):  # the node reports once a second
                self.client.wait_for(lambda latest: latest.diagnostics, timeout=2.5)
            status = self.client.master_status()
            if not status:
                self.out("no diagnostics received yet")
            for key, value in status.items():
                self.out(f"  {key:24} {value}")
        elif command.what == "layout":
            layout = self.client.latest.layout
            if layout is None:
                self.out("no layout received yet (is the node configured?)")
                return
            for s in layout.slaves:
                if command.slave is not None and s.name != command.slave:
                    continue
                self.out(f"{s.name} (position {s.position}, {s.device})")
                for kind, variables in (("out", s.outputs), ("in", s.inputs)):
                    for v in variables:
                        lo, hi = format_value(v.minimum, v), format_value(v.maximum, v)
                        self.out(f"  {kind:3} {v.name:24} {v.address}  {v.type:7} {lo}..{hi}")

    def run_sequence(self, path: str, step: bool = False) -> bool:
        sequence = load_sequence(path, self.context())
        total = len(sequence.steps)
        self.out(
            f"sequence {sequence.path}: {total} steps, {sequence.duration_s:g} s of waits"
            + (f" — {sequence.description}" if sequence.description else "")
        )
        try:
            for s in sequence.steps:
                if step:
                    answer = self.confirm(f"[{s.number}/{total}] {s.text}  (Enter/s/q) ")
                    if answer.strip().lower() == "q":
                        self.out("sequence stopped")
                        return True
                    if answer.strip().lower() == "s":
                        continue
                self.out(f"[{s.number}/{total}] {s.text}")
                if not self.execute(s.command):
                    self.out(f"sequence stopped at step {s.number}")
                    return False
        except KeyboardInterrupt:
            self.out("sequence interrupted (outputs stay as last commanded; 'panic' for safe)")
            return False
        return True


def repl(
    console: Console,
    history: Path | None = HISTORY_FILE,
    input: Any = None,
    output: Any = None,
) -> int:
    """The interactive loop with history, completion and the panic keys (``input``/``output``:
    prompt_toolkit I/O, for driving the console from tests)."""
    from prompt_toolkit import PromptSession
    from prompt_toolkit.application import run_in_terminal
    from prompt_toolkit.history import FileHistory, InMemoryHistory
    from prompt_toolkit.key_binding import KeyBindings, KeyPressEvent

    from ether_ros.console.completion import ConsoleCompleter

    bindings = KeyBindings()

    def on_panic(event: KeyPressEvent) -> None:
        run_in_terminal(console.panic)

    for key in PANIC_KEYS:
        bindings.add(key, eager=True)(on_panic)

    hist: Any = InMemoryHistory()
    if history is not None:
        try:
            history.touch(exist_ok=True)
            hist = FileHistory(str(history))
        except OSError:
            pass
    session: PromptSession[str] = PromptSession(
        history=hist,
        completer=ConsoleCompleter(console.context),
        key_bindings=bindings,
        complete_while_typing=False,
        input=input,
        output=output,
    )
    console.out(
        f"ether_ros console — node {console.client.target}. 'help' for commands; "
        "Ctrl-P or F1: PANIC."
    )
    while True:
        try:
            text = session.prompt("ether_ros> ")
        except KeyboardInterrupt:
            continue
        except EOFError:
            return 0
        if not console.line(text):
            return 0


def run_lines(console: Console, lines: list[str]) -> int:
    """Non-interactive: run lines in order, stop at the first error (exit code 1)."""
    for text in lines:
        try:
            command = parse_command(text, console.context())
        except CommandError as exc:
            console.out(f"error: {exc}")
            return 1
        if command is None:
            continue
        try:
            if not console.execute(command):
                return 1
        except QuitConsole:
            return 0
        except EtherRosError as exc:
            console.out(f"error: {exc}")
            return 1
    return 0
