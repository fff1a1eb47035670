"""The operator console's commands: :class:`Console` runs parsed console lines against a running
ether_ros node over ROS 2.

Every line goes through :func:`ether_ros.console.commands.parse_command` first; an invalid line
gets its reason and nothing is sent. Panic has a path of its own
(:class:`ether_ros.ros.panic_line.PanicLine`): it never waits for a running command, and it
interrupts one. A running command stops at its next interruption point when
:meth:`Console.interrupt` is called (a panic, Ctrl-C): a ``wait`` at once, a sequence before its
next step, a step-mode question at once; a request already sent to the node is not recalled (the
console takes its answer first).

The interactive loop that reads the keys while commands run is
:mod:`ether_ros.console.interactive`; :func:`run_lines` runs lines without a terminal.
"""

from __future__ import annotations

import contextlib
import enum
import threading
import time
from collections.abc import Callable, Iterable
from dataclasses import replace
from typing import IO

from ether_ros.config.types import format_number
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
from ether_ros.console.keys import LINE_LIMIT
from ether_ros.console.sequence import Step, load_sequence
from ether_ros.errors import EtherRosError
from ether_ros.ros.client import EtherRosClient, Latest, make_write
from ether_ros.ros.freshness import describe_age
from ether_ros.ros.panic_line import PanicLine
from ether_ros.ros.values import format_value

SENT_MEMORY_S = 2.0
# How long a check that needs the node's outputs waits for the first outputs message of a
# freshly started console (a node publishes them every pdo_out period; `-c` runs at once, and
# on a loaded host the first message can take seconds). The wait ends early when they arrive,
# and at once when the command is interrupted.
FIRST_OUTPUTS_WAIT_S = 10.0
# How long a move waits for the node to refuse it (it answers only refusals).
MOVE_ANSWER_S = 0.3
# `states` asks the node for its lifecycle state with this timeout (a dead node never answers).
STATE_TIMEOUT_S = 2.0
# How long a write waits for the node's answer (as long as an SDO transfer: a node on a loaded
# machine may take seconds; a panic never waits for it).
WRITE_TIMEOUT_S = 10.0
# What a successful panic answer adds: the console command that clears it.
CLEAR_HINT = "type 'clear' to end it (outputs stay safe until you command them again)"
# What the console adds to the node's answer to a clear: nothing commanded before the panic
# comes back by itself (ISO 13850), whatever node version answered.
CLEARED_NOTE = "panic cleared: outputs stay at their safe values until you command them again"


class Outcome(enum.Enum):
    OK = "ok"
    FAILED = "failed"  # refused, an error, or interrupted
    QUIT = "quit"


class Interrupted(Exception):
    """The running command was interrupted (``reason``: "panic", "Ctrl-C", ...)."""

    def __init__(self, reason: str) -> None:
        super().__init__(reason)
        self.reason = reason


class QuitConsole(Exception):
    pass


class Console:
    """Executes parsed commands against the node; prints through ``out``.

    ``confirm(question)`` answers step mode's questions (None: no answer, the sequence stops);
    by default it reads a line from stdin. ``panic_line``: the path to the node's panic service
    (one of its own by default, closed by :meth:`close`)."""

    def __init__(
        self,
        client: EtherRosClient,
        out: Callable[[str], None] = print,
        confirm: Callable[[str], str | None] | None = None,
        panic_line: PanicLine | None = None,
    ) -> None:
        self.client = client
        self.out = out
        self.confirm = confirm or _ask_stdin
        # What this console wrote recently, until the node's snapshots (pdo_out_timer, every
        # ros.snapshot_period_ms) have surely caught up: the next command is checked against
        # the values just sent, not against a snapshot from before them.
        self._sent: dict[tuple[str, str], tuple[float, float]] = {}
        self._axes: dict[str, JointLimits] | None = None  # from the node's parameters, once
        # joint → (CiA 402 state, when) as answered to this console's own axis commands.
        self._answered: dict[str, tuple[str, float]] = {}
        # Set to stop the running command at its next interruption point.
        self.cancel = threading.Event()
        self._reason = ""
        # When this console last had a lifecycle command answered (start, stop, restart): the
        # node's reports from before it show the old states.
        self._lifecycle_at = 0.0
        self._own_panic_line = panic_line is None
        self.panic_line = panic_line or PanicLine(
            client.prefix, client.node.context, report=lambda m: self.out(m), hint=CLEAR_HINT
        )
        # A panic, however it was sent, interrupts the running command.
        self.panic_line.on_press.append(lambda: self.interrupt("panic"))

    def close(self) -> None:
        self.interrupt("the console is closing")
        if self._own_panic_line:
            self.panic_line.close()

    def __enter__(self) -> Console:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def interrupt(self, reason: str) -> None:
        """Stop the running command at its next interruption point (from any thread)."""
        self._reason = reason
        self.cancel.set()

    def _check(self) -> None:
        if self.cancel.is_set():
            raise Interrupted(self._reason or "interrupted")

    def _wait(self, seconds: float) -> None:
        """A wait that ends at once when the command is interrupted."""
        if self.cancel.wait(seconds):
            raise Interrupted(self._reason or "interrupted")

    def context(self) -> ConsoleContext:
        """The layout and the last commanded outputs (``pdo_out_timer``; the wire echo when no
        snapshot arrived yet), for checking writes."""
        latest = self.client.latest
        if latest.layout is not None and not self._outputs_known(latest):
            # A console started a moment ago has the layout but not yet every slave's outputs
            # (pdo_out comes a slave per message): wait for them (briefly) instead of refusing
            # a write it could check.
            deadline = time.monotonic() + FIRST_OUTPUTS_WAIT_S
            while time.monotonic() < deadline:
                self._check()
                with contextlib.suppress(EtherRosError):
                    self.client.wait_for(self._outputs_known, 0.2)
                    break
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

    @staticmethod
    def _outputs_known(latest: Latest) -> bool:
        """Every slave of the layout that has outputs has them in the console's view (the
        node's pdo_out or pdo_out_timer)."""
        layout = latest.layout
        if layout is None:
            return False
        return all(
            s.name in latest.outputs or s.name in latest.commanded
            for s in layout.slaves
            if s.outputs
        )

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
        return self.run_line(text) is not Outcome.QUIT

    def run_line(self, text: str) -> Outcome:
        """Parse and run one line (from a fresh start: an earlier interrupt is forgotten)."""
        self.cancel.clear()
        self._reason = ""
        try:
            if len(text.encode(errors="replace")) > LINE_LIMIT:
                raise CommandError(f"the line is longer than {LINE_LIMIT} bytes: refused")
            command = parse_command(text, self.context())
            if command is None:
                return Outcome.OK
            return Outcome.OK if self.execute(command) else Outcome.FAILED
        except QuitConsole:
            return Outcome.QUIT
        except Interrupted as exc:
            self.out(f"interrupted ({exc.reason})")
            return Outcome.FAILED
        except EtherRosError as exc:
            self.out(f"error: {exc}")
            return Outcome.FAILED

    def panic(self) -> tuple[bool, str]:
        """Send the panic (the panic line reports the answer) and wait for the answer. A panic
        that is a command (typed, or a sequence step) does not interrupt the command itself."""
        answer = self.panic_line.press(hooks=False)
        answer.wait(self.panic_line.answer_timeout + 1.0)
        return answer.ok, ""

    def _control(self, command: str) -> tuple[bool, str]:
        if command == "panic":
            return self.panic()
        sent = time.monotonic()
        ok, message = self.client.command(command)
        if command in ("start", "stop", "restart"):
            self._lifecycle_at = time.monotonic()
        if command == "clear_panic" and ok:
            # The node reset every output to its safe value: what this console sent before,
            # and the node's snapshots from before the clear, no longer describe the outputs.
            self._sent.clear()
            self.client.forget_commanded()
            if "safe values" not in message:
                message = f"{message} — {CLEARED_NOTE}" if message else CLEARED_NOTE
        if self.panic_line.last_press > sent:
            # A panic key was pressed while this command (a clear, a start) was on its way:
            # the node may have served the panic first. The panic stands: send it again.
            self.panic_line.press(hooks=False)
            message += " — a panic was pressed meanwhile and has been sent again"
        return ok, message

    def execute(self, command: Command) -> bool:
        """Run one command; False when the node refused it (the reason is printed)."""
        ok, message = True, ""
        if isinstance(command, Control):
            ok, message = self._control(command.command)
        elif isinstance(command, Write):
            writes = [make_write(op.slave, op.variable, op.value) for op in command.ops]
            ok, message = self.client.write_many(writes, timeout=WRITE_TIMEOUT_S)
            if ok:
                now = time.monotonic()
                for op in command.ops:
                    self._sent[(op.slave, op.variable)] = (op.value, now)
        elif isinstance(command, Get):
            self._get(command)
        elif isinstance(command, Show):
            ok = self._show(command)
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
            self._wait(command.seconds)
        elif isinstance(command, AxisOp):
            ok, message, states = self.client.axis_command(command.command, list(command.joints))
            self._note_answered(states)
        elif isinstance(command, SetMode):
            ok, message, states = self.client.set_mode(command.mode, list(command.joints))
            self._note_answered(states)
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
        """``move``: refused at once when the axis's last reported state says it cannot move
        (nothing is published); else published, and the answer is the node's refusal, or the
        axis's state afterwards: never a bare "sent" for a command that moved nothing."""
        what = f"{command.joint} {command.array}={command.value:g}"
        blocked = self._axis_blocked(command.joint)
        if blocked:
            return False, f"not executed: {what}: {blocked}"
        before = len(self.client.joint_results)
        self.client.publish_joint_command([command.joint], **{command.array: [command.value]})
        try:  # the node answers refusals only
            self.client.wait_for(lambda _l: len(self.client.joint_results) > before, MOVE_ANSWER_S)
        except EtherRosError:
            blocked = self._axis_blocked(command.joint)
            if blocked:
                return False, f"not executed: {what}: {blocked}"
            state = self.client.axis_states().get(command.joint, {}).get("state")
            if state is None:
                return True, f"accepted {what} (the axis's state is not reported yet)"
            return True, f"accepted {what} ({command.joint}: {state})"
        result = self.client.joint_results[before]
        message = str(result.message)
        if not result.success and not message.startswith("not executed"):
            message = f"not executed: {message}"
        return bool(result.success), message

    def _note_answered(self, states: dict[str, str]) -> None:
        """The CiA 402 states the node answered to this console's own axis command: newer
        than the diagnostics until their next report (a `disable` then `move` must not be
        answered from a report made before the disable)."""
        now = time.monotonic()
        for joint, state in states.items():
            self._answered[joint] = (state, now)

    def _axis_blocked(self, joint: str) -> str:
        """Why the joint cannot move, as the node last said: the answer to this console's own
        axis command when it is newer than the diagnostics' last report, else that report (a
        fresh one only; "" when it can, or when nothing fresh says otherwise)."""
        diag = self.client.latest.arrivals
        age = diag.age("diagnostics")
        answered = self._answered.get(joint)
        if answered is not None and (age is None or time.monotonic() - answered[1] < age):
            state = answered[0]
            if state in ("fault", "fault_reaction_active"):
                return f"in fault ({state}): reset_fault, then enable"
            if state != "operation_enabled":
                return f"not enabled ({state}): enable it first"
            return ""
        if age is not None and not diag.fresh("diagnostics"):
            return ""
        return self.client.axis_states().get(joint, {}).get("blocked", "")

    def _get(self, command: Get) -> None:
        latest = self.client.latest
        groups = (
            ("inputs", "inputs", latest.inputs.get(command.slave, {})),
            ("outputs (on the wire)", "outputs", latest.outputs.get(command.slave, {})),
        )
        if command.variable is not None:
            for label, kind, values in groups:
                if command.variable in values:
                    shown = self._format(command.slave, command.variable, values[command.variable])
                    self.out(f"{command.slave}.{command.variable} = {shown}")
                    self.out(f"  ({label}{self._staleness(f'{kind}/{command.slave}')})")
                    return
            self.out(f"no value of {command.variable} received yet")
            return
        for label, kind, values in groups:
            self.out(f"{command.slave} {label}{self._staleness(f'{kind}/{command.slave}')}:")
            if not values:
                self.out("  (nothing received yet)")
            for name, value in values.items():
                self.out(f"  {name:24} {self._format(command.slave, name, value)}")

    def _format(self, slave: str, variable: str, value: float) -> str:
        """A value as its variable's type prints (an int32 never in exponent notation)."""
        layout = self.client.latest.layout
        for s in layout.slaves if layout is not None else ():
            if s.name == slave:
                for v in (*s.outputs, *s.inputs):
                    if v.name == variable:
                        return format_value(value, v)
        return format_number(value)

    def _staleness(self, key: str) -> str:
        """ "" for a fresh report; else what to print after its label."""
        arrivals = self.client.latest.arrivals
        age = arrivals.age(key)
        if age is None or arrivals.fresh(key):
            return ""
        return f" — STALE: received {describe_age(age)} ago, the node is gone or stalled"

    def _show(self, command: Show) -> bool:
        if command.what == "states":
            return self._states()
        if command.what == "stats":
            return self._stats()
        layout = self.client.latest.layout
        if layout is None:
            self.out("no layout received yet (is the node configured?)")
            return True
        for s in layout.slaves:
            if command.slave is not None and s.name != command.slave:
                continue
            self.out(f"{s.name} (position {s.position}, {s.device})")
            for kind, variables in (("out", s.outputs), ("in", s.inputs)):
                for v in variables:
                    lo, hi = format_value(v.minimum, v), format_value(v.maximum, v)
                    self.out(f"  {kind:3} {v.name:24} {v.address}  {v.type:7} {lo}..{hi}")
        return True

    def _states(self) -> bool:
        """The node's lifecycle state and the slaves' AL states from a report that is fresh
        (not older than two of the node's periods) and came after this console's last `start`,
        `stop` or `restart` — else from the next one: the slaves are never shown from an old
        report (right after a `start` the last one still says INIT, and a dead node's last one
        says OP)."""
        asked = time.monotonic()
        arrivals = self.client.latest.arrivals
        try:
            state = self.client.get_state(timeout=STATE_TIMEOUT_S)
        except EtherRosError as exc:
            self.out(f"node {self.client.target}: gone — it does not answer ({exc})")
            age = arrivals.age("diagnostics")
            seen = "none received" if age is None else f"the last is {describe_age(age)} old"
            self.out(f"  slave states unknown: no report from the node ({seen})")
            return False
        self.out(f"node {self.client.target}: {state}")
        last = arrivals.last.get("diagnostics", 0.0)
        current = last > self._lifecycle_at and arrivals.fresh("diagnostics")
        if not current and not self._wait_report(asked):
            age = arrivals.age("diagnostics")
            seen = "none received" if age is None else f"the last is {describe_age(age)} old"
            self.out(
                f"  slave states unknown: no new report within "
                f"{describe_age(arrivals.stale_after('diagnostics'))} ({seen})"
            )
            return False
        states = self.client.slave_states()
        if not states:
            self.out("  (the node reports no slaves)")
        for slave, al in states.items():
            self.out(f"  {slave:24} {al}")
        for joint, kv in self.client.axis_states().items():
            # Each CiA 402 axis as it really is: a stopped axis says why it will not move.
            line = f"  axis {joint:19} {kv.get('state', '?')} ({kv.get('mode', '?')})"
            if kv.get("level") not in (None, "OK") or kv.get("blocked"):
                line += f": {kv.get('message', '')}"
            self.out(line)
        return True

    def _wait_report(self, after: float) -> bool:
        """Wait (interruptibly) for a diagnostics report that arrived after ``after``
        (monotonic), at most two of the node's periods; True when one did."""
        arrivals = self.client.latest.arrivals
        with contextlib.suppress(EtherRosError):
            self.client.wait_for(
                lambda _l: self.cancel.is_set() or arrivals.last.get("diagnostics", 0.0) > after,
                timeout=arrivals.stale_after("diagnostics"),
            )
        self._check()
        return arrivals.last.get("diagnostics", 0.0) > after

    def _stats(self) -> bool:
        arrivals = self.client.latest.arrivals
        if arrivals.age("diagnostics") is None:  # none yet: the node reports once a period
            self._wait_report(0.0)
        status = self.client.master_status()
        if not status:
            self.out("no diagnostics received yet")
            return False
        stale = self._staleness("diagnostics")
        if stale:
            self.out(f"the node's last report{stale}; the values below are from then")
        for key, value in status.items():
            self.out(f"  {key:24} {value}")
        return not stale

    def run_sequence(self, path: str, step: bool = False) -> bool:
        sequence = load_sequence(path, self.context())
        total = len(sequence.steps)
        self.out(
            f"sequence {sequence.path}: {total} steps, {sequence.duration_s:g} s of waits"
            + (f" — {sequence.description}" if sequence.description else "")
        )
        number = 0
        try:
            for s in sequence.steps:
                number = s.number
                self._check()
                if step:
                    decision = self._ask_step(s, total)
                    if decision == "stop":
                        self.out(f"sequence stopped before step {s.number}")
                        return True
                    if decision == "skip":
                        self.out(f"[{s.number}/{total}] skipped")
                        continue
                self.out(f"[{s.number}/{total}] {s.text}")
                if not self.execute(s.command):
                    self.out(f"sequence stopped at step {s.number}")
                    return False
        except (Interrupted, KeyboardInterrupt) as exc:
            reason = exc.reason if isinstance(exc, Interrupted) else "Ctrl-C"
            after = (
                "safe outputs on the wire"
                if reason == "panic"
                else "outputs stay as last commanded; 'panic' for safe outputs"
            )
            self.out(f"sequence interrupted at step {number} ({reason}): {after}")
            return False
        return True

    def _ask_step(self, s: Step, total: int) -> str:
        """Step mode: "run" only on an explicit yes; "skip" or "stop" otherwise."""
        question = f"[{s.number}/{total}] {s.text} — run it? y(es) / s(kip) / n(o: stop) "
        while True:
            answer = self.confirm(question)
            self._check()
            if answer is None:
                return "stop"
            word = answer.strip().lower()
            if word in ("y", "yes"):
                return "run"
            if word in ("n", "no", "q", "quit"):
                return "stop"
            if word in ("s", "skip"):
                if isinstance(s.command, Write):
                    self.out(
                        "a write cannot be skipped: the later steps were checked with it "
                        "applied; answer y or n"
                    )
                    continue
                return "skip"
            self.out(f"answer y (run the step), s (skip it) or n (stop), not '{answer.strip()}'")


def _ask_stdin(question: str) -> str | None:
    try:
        return input(question)
    except EOFError:
        return None


def run_lines(console: Console, lines: Iterable[str]) -> int:
    """Non-interactive: run lines in order, stop at the first error (exit code 1)."""
    for text in lines:
        try:
            outcome = console.run_line(text)
        except KeyboardInterrupt:
            console.out("interrupted (Ctrl-C)")
            return 1
        if outcome is Outcome.QUIT:
            return 0
        if outcome is Outcome.FAILED:
            return 1
    return 0


def bounded_lines(stream: IO[bytes], limit: int = LINE_LIMIT) -> Iterable[str]:
    """The lines of ``stream`` one at a time (never more than one in memory); a line longer
    than ``limit`` bytes is given cut at ``limit + 1`` bytes (the rest skipped), which
    :meth:`Console.run_line` refuses."""
    while True:
        raw = stream.readline(limit + 1)
        if not raw:
            return
        if len(raw) > limit and not raw.endswith(b"\n"):
            while True:  # skip the rest of the overlong line
                rest = stream.readline(65536)
                if not rest or rest.endswith(b"\n"):
                    break
        yield raw.decode(errors="replace").rstrip("\r\n")
