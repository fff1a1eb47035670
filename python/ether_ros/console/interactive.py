"""The console on a terminal: the keys are read all the time, commands run on a worker.

Three threads, each with one job:

- the **key guard** (:class:`ether_ros.console.keys.KeyGuard`) reads the terminal: a panic key
  is sent from there at once (:class:`ether_ros.ros.panic_line.PanicLine`), Ctrl-C interrupts the
  running command, overlong lines and pastes are refused; the rest goes to the prompt;
- the **prompt** (prompt_toolkit, this module's event loop) edits lines with history and
  completion, and is there while a command runs: its text shows what runs, and step mode's
  questions are answered on it;
- the **worker** runs one command (or sequence) at a time (:meth:`Console.run_line`). A line
  entered while it is busy is not queued: it is refused and put back on the line (except
  ``panic``, which goes ahead, and the answer to a step-mode question).

With ``lines`` (``console -c ...`` / ``--run`` on a terminal) the lines run in order, the keys
still work, and the console ends after the last one (or the first that fails).
"""

from __future__ import annotations

import asyncio
import contextlib
import os
import signal
import sys
import threading
from collections.abc import Iterable
from pathlib import Path
from typing import Any

from ether_ros.console.app import Console, Outcome
from ether_ros.console.commands import CommandError, ConsoleContext, Control, Quit, parse_command
from ether_ros.console.keys import LINE_LIMIT, KeyGuard

HISTORY_FILE = Path.home() / ".ether_ros_console_history"
PROMPT = "ether_ros> "


class _Question:
    """A step-mode question waiting for the operator's line."""

    def __init__(self, text: str) -> None:
        self.text = text
        self.answer: str | None = None
        self.answered = threading.Event()

    def give(self, answer: str) -> None:
        self.answer = answer
        self.answered.set()


class Repl:
    def __init__(
        self,
        console: Console,
        history: Path | None = HISTORY_FILE,
        lines: Iterable[str] | None = None,
        fd: int | None = None,
        output: Any = None,
    ) -> None:
        self.console = console
        self.history = history
        self.preset = list(lines) if lines is not None else None
        self.fd = sys.stdin.fileno() if fd is None else fd
        self.output = output
        self.status = 0
        self.running = ""  # the line the worker runs ("" when idle); read by the key guard
        self.question: _Question | None = None
        self.ended = False  # the terminal is gone or a signal asked us to end
        self._quit = False
        self._default = ""  # text put back on the next prompt's line
        self._worker: threading.Thread | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._session: Any = None
        console.confirm = self.ask

    # ------------------------------------------------------------------ called from other threads
    def ask(self, question: str) -> str | None:
        """Step mode (the worker): show ``question`` on the prompt and wait for the next line;
        None when the command is interrupted or the console ends."""
        q = _Question(question)
        self.question = q
        self._soon(self._redraw)
        try:
            while not q.answered.wait(0.05):
                if self.console.cancel.is_set() or self.ended:
                    return None
            return q.answer
        finally:
            self.question = None
            self._soon(self._redraw)

    def _soon(self, callback: Any, *args: Any) -> None:
        loop = self._loop
        if loop is not None and not loop.is_closed():
            with contextlib.suppress(RuntimeError):  # the loop is closing
                loop.call_soon_threadsafe(callback, *args)

    def _refused(self, message: str, clear_line: bool) -> None:
        self.console.out(message)
        if clear_line:
            self._soon(self._clear_line)

    def _work(self, text: str) -> None:
        try:
            outcome = self.console.run_line(text)
        except Exception as exc:  # the console outlives any command
            self.console.out(f"error: {type(exc).__name__}: {exc}")
            outcome = Outcome.FAILED
        if outcome is Outcome.QUIT:
            self._quit = True
        elif outcome is Outcome.FAILED and self.preset is not None:
            self.status = 1
        self.running = ""
        self._soon(self._job_done)

    # ------------------------------------------------------------------ the event loop's side
    def _app(self) -> Any:
        return self._session.app if self._session is not None else None

    def _redraw(self) -> None:
        app = self._app()
        if app is not None and app.is_running:
            app.invalidate()

    def _clear_line(self) -> None:
        if self._session is not None:
            self._session.default_buffer.reset()

    def _exit_prompt(self, **how: Any) -> None:
        app = self._app()
        if app is not None:
            with contextlib.suppress(Exception):  # not running, or already leaving
                app.exit(**how)

    def _job_done(self) -> None:
        if self.preset is not None or self._quit:
            self._exit_prompt(result=None)  # on to the next line, or out
        else:
            self._redraw()

    def _pre_run(self) -> None:
        # The job may have ended before this prompt started (its _job_done found none).
        if (self.preset is not None or self._quit) and not self.running:
            self._exit_prompt(result=None)

    def _end(self, why: str) -> None:
        """The terminal is gone, or SIGTERM/SIGINT: interrupt the command and leave."""
        self.ended = True
        self.console.interrupt(why)
        self._exit_prompt(exception=EOFError)

    def _message(self) -> str:
        if self.question is not None:
            return self.question.text
        if self.running:
            shown = self.running if len(self.running) <= 40 else self.running[:37] + "..."
            return f"[running: {shown} — Ctrl-C stops it, Ctrl-P panics] "
        return PROMPT

    def _start(self, text: str) -> None:
        self.running = text.strip() or "(empty)"
        self._worker = threading.Thread(
            target=self._work, args=(text,), name="ether_ros-console-worker", daemon=True
        )
        self._worker.start()

    def _submit(self, text: str) -> None:
        """A line the operator entered."""
        question = self.question
        if question is not None:
            question.give(text)
            return
        if not text.strip():
            return
        if len(text.encode(errors="replace")) > LINE_LIMIT:
            self.console.out(f"line refused: longer than {LINE_LIMIT} bytes; nothing was run")
            if self.preset is not None:
                self.status = 1
            return
        try:  # without the layout: only what needs none (panic, quit) is recognised here
            quick = parse_command(text, ConsoleContext(None))
        except CommandError:
            quick = None
        if quick == Control("panic") and self.running:
            self.console.panic_line.press()  # ahead of the command, and it stops it
            return
        if isinstance(quick, Quit):
            if self.running:
                self.console.out(f"'{self.running}' is running: Ctrl-C stops it first")
                return
            self._quit = True
            return
        if self.running:
            self.console.out(
                f"busy: '{self.running}' is running (Ctrl-C stops it, Ctrl-P panics); "
                f"'{text.strip()}' was not run — it is back on the line"
            )
            self._default = text
            return
        self._start(text)

    async def run(self) -> int:
        from prompt_toolkit import PromptSession
        from prompt_toolkit.history import FileHistory, History, InMemoryHistory
        from prompt_toolkit.input.posix_pipe import PosixPipeInput
        from prompt_toolkit.input.vt100 import raw_mode
        from prompt_toolkit.key_binding import KeyBindings, KeyPressEvent
        from prompt_toolkit.output import create_output
        from prompt_toolkit.patch_stdout import patch_stdout

        from ether_ros.console.completion import ConsoleCompleter

        self._loop = asyncio.get_running_loop()
        panic_line = self.console.panic_line
        bindings = KeyBindings()

        # The key guard takes the panic keys out before the prompt sees them; these catch an
        # F1 whose bytes a read happened to split.
        def panic() -> None:
            if panic_line.watching:
                panic_line.claim_keys()  # the native reader has sent it already
            else:
                panic_line.press()

        @bindings.add("c-p", eager=True)
        @bindings.add("f1", eager=True)
        def _panic(event: KeyPressEvent) -> None:
            panic()

        class BoundedHistory(FileHistory):
            """The history file without lines the console would refuse anyway."""

            def load_history_strings(self) -> Iterable[str]:
                for line in super().load_history_strings():
                    if len(line.encode(errors="replace")) <= LINE_LIMIT:
                        yield line

        hist: History = InMemoryHistory()
        if self.history is not None:
            try:
                self.history.touch(exist_ok=True)
                hist = BoundedHistory(str(self.history))
            except OSError:
                pass
        output = self.output or create_output(sys.stdout)
        with contextlib.ExitStack() as stack:
            pipe = stack.enter_context(PosixPipeInput.create())
            stack.enter_context(raw_mode(self.fd))
            stack.enter_context(patch_stdout())
            self._session = PromptSession(
                history=hist,
                completer=ConsoleCompleter(self.console.context),
                key_bindings=bindings,
                complete_while_typing=False,
                input=pipe,
                output=output,
            )
            # The terminal -> the native key reader (sends a panic at once) -> a pipe -> the
            # key guard (bounds, Ctrl-C) -> the prompt. Without the native reader, the guard
            # reads the terminal and sends the panic itself.
            keys = panic_line.watch_terminal(self.fd)
            if keys is not None:
                stack.callback(os.close, keys)
                stack.callback(panic_line.stop_watching)
            guard = KeyGuard(
                self.fd if keys is None else keys,
                pipe.pipe.write_fd,
                busy=lambda: bool(self.running),
                on_panic=panic,
                on_interrupt=lambda: self.console.interrupt("Ctrl-C"),
                on_refused=self._refused,
                on_end=lambda: self._soon(self._end, "the terminal is gone"),
                after_read=None if keys is None else panic_line.claim_keys,
            )
            guard.start()
            stack.callback(guard.stop)
            for sig in (signal.SIGTERM, signal.SIGINT, signal.SIGHUP):
                self._loop.add_signal_handler(sig, self._end, signal.Signals(sig).name)
                stack.callback(self._loop.remove_signal_handler, sig)
            if self.preset is None:
                self.console.out(
                    f"ether_ros console — node {self.console.client.target}. 'help' for "
                    "commands; Ctrl-P or F1: PANIC (also while a command runs); "
                    "Ctrl-C stops the running command."
                )
            try:
                return await self._prompt_loop(guard)
            finally:
                self.console.interrupt("the console is closing")
                if self._worker is not None:
                    self._worker.join(timeout=5)

    async def _prompt_loop(self, guard: KeyGuard) -> int:
        while True:
            if self._quit:
                return self.status
            if self.preset is not None and not self.running:
                if self.status != 0 or not self.preset:
                    return self.status
                self._submit(self.preset.pop(0))
                continue
            default, self._default = self._default, ""
            guard.filter.line_started(len(default.encode(errors="replace")))
            try:
                text = await self._session.prompt_async(
                    self._message, default=default, pre_run=self._pre_run
                )
            except KeyboardInterrupt:  # Ctrl-C at the prompt: the line is dropped
                continue
            except EOFError:  # Ctrl-D on an empty line, or the end
                if self.ended:
                    return self.status or (0 if self.preset is None else 1)
                if self.running:
                    self.console.out(f"'{self.running}' is running: Ctrl-C stops it first")
                    continue
                return self.status
            if text is not None:
                self._submit(text)


def repl(
    console: Console,
    history: Path | None = HISTORY_FILE,
    lines: Iterable[str] | None = None,
    fd: int | None = None,
    output: Any = None,
) -> int:
    """The interactive console on the terminal ``fd`` (stdin by default); with ``lines``, run
    them in order and end (exit status 1 at the first that fails). ``output``: prompt_toolkit
    output (default: the terminal on stdout)."""
    return asyncio.run(Repl(console, history, lines, fd, output).run())
