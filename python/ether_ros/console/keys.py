"""The console's keyboard: one thread reads the terminal, and panic comes first.

The prompt (prompt_toolkit) never reads the terminal itself. The native key reader
(``ether_ros._native.PanicKeys``, started by :meth:`ether_ros.ros.panic_line.PanicLine.
watch_terminal`) reads it in raw mode and sends the panic request the moment a panic key
arrives, without Python; it passes the bytes on to a thread of ours (:class:`KeyGuard`), which
looks at every chunk before anything else happens to it (:class:`KeyFilter`):

1. **panic keys** — Ctrl-P and F1 (``ESC O P``, ``ESC [ 1 1 ~``, the Linux console's
   ``ESC [ [ A``) anywhere in the chunk are taken out; the guard picks up what the native
   reader sent (or, without it, sends the panic itself);
2. **Ctrl-C while a command runs** interrupts that command (and is taken out); at the prompt it
   goes on to the prompt, which clears the line;
3. **bounds** — a line longer than :data:`LINE_LIMIT` bytes, a bracketed paste longer than that,
   or a paste of several lines is refused: discarded up to its end (the end of the line, the end
   of the paste, or :data:`QUIET_S` without input) with one message, and never reaches the
   prompt, so nothing of it is run and nothing is spent absorbing it;
4. the rest goes to the prompt through a pipe.

So a panic key acts within one read of the terminal whatever the prompt, the command worker or
the ROS executor are doing, and a 100k-character paste costs a few reads.
"""

from __future__ import annotations

import contextlib
import os
import re
import select
import threading
from collections.abc import Callable
from dataclasses import dataclass

from ether_ros import _native

# A console line is a command: a few hundred bytes at most (a `set all` of ten variables).
LINE_LIMIT = 1024
# Input stops for this long: a refused paste without a line end is over.
QUIET_S = 0.25
READ_CHUNK = 65536

CTRL_C = b"\x03"
# Ctrl-P and F1 (as xterm, VT220/rxvt and the Linux console send it): the native key reader's
# list, the one definition.
PANIC_SEQUENCES = tuple(_native.PANIC_KEYS)
PASTE_START = b"\x1b[200~"
PASTE_END = b"\x1b[201~"

# Tokens of the input stream: paste brackets, line ends, line resets (Ctrl-C, Ctrl-U), escape
# sequences (cursor keys: forwarded, not counted as line text), a lone ESC, and runs of text.
_TOKENS = re.compile(
    rb"\x1b\[20[01]~"
    rb"|[\r\n]"
    rb"|[\x03\x15]"
    rb"|\x1b\[[0-9;?]*[ -/]*[@-~]|\x1bO[@-~]|\x1b[@-Z\\-_]"
    rb"|\x1b"
    rb"|[^\r\n\x03\x15\x1b]+"
)
_ESCAPE = re.compile(rb"\x1b(\[|O|[@-Z\\-_])")


@dataclass
class Filtered:
    """What one chunk of input amounts to."""

    forward: bytes = b""  # what the prompt gets
    panic: bool = False
    interrupt: bool = False  # Ctrl-C while a command runs
    refused: str = ""  # a line or paste was refused: this message says why
    clear_line: bool = False  # the prompt must drop what it has of the refused line


class KeyFilter:
    """The pure part of the guard: bytes in, what to do out (see the module docstring).

    Thread-safe: :meth:`feed` (the reading thread) and :meth:`line_started` (the prompt) may
    be called concurrently."""

    def __init__(self, limit: int = LINE_LIMIT) -> None:
        self.limit = limit
        self._lock = threading.Lock()
        self._line = 0  # bytes of text on the current line, as far as the guard knows
        self._paste: bytearray | None = None  # inside a bracketed paste: its bytes so far
        self._discard: str = ""  # "line" | "paste" while dropping a refused input up to its end

    @property
    def discarding(self) -> bool:
        return bool(self._discard)

    def line_started(self, length: int = 0) -> None:
        """The prompt shows a fresh line holding ``length`` bytes (its default text)."""
        with self._lock:
            self._line = length

    def feed(self, data: bytes, busy: bool) -> Filtered:
        out = Filtered()
        for key in PANIC_SEQUENCES:  # first, whatever else the chunk holds
            if key in data:
                out.panic = True
                data = data.replace(key, b"")
        if busy and CTRL_C in data:
            out.interrupt = True
            data = data.replace(CTRL_C, b"")
        forward = bytearray()
        with self._lock:
            for m in _TOKENS.finditer(data):
                self._token(m.group(), forward, out)
        out.forward = bytes(forward)
        return out

    def quiet(self) -> Filtered:
        """No input for :data:`QUIET_S`: a refused input without a proper end is over."""
        with self._lock:
            if self._discard:
                self._discard = ""
                self._paste = None
        return Filtered()

    def _refuse(self, out: Filtered, why: str, until: str) -> None:
        out.refused = why
        out.clear_line = True
        self._discard, self._paste, self._line = until, None, 0

    def _token(self, token: bytes, forward: bytearray, out: Filtered) -> None:
        if self._discard == "paste":
            if token == PASTE_END:
                self._discard = ""
            return
        if self._discard == "line":
            if token in (b"\r", b"\n", CTRL_C):
                self._discard = ""  # the line end is dropped too: nothing is run
            return
        if self._paste is not None:
            if token == PASTE_END:
                self._end_paste(forward, out)
            elif len(self._paste) + len(token) > self.limit:
                self._refuse(
                    out, f"paste refused: longer than {self.limit} bytes — discarded", "paste"
                )
            else:
                self._paste += token
            return
        if token == PASTE_START:
            self._paste = bytearray()
        elif token == PASTE_END:
            pass  # a stray end of paste
        elif token in (b"\r", b"\n", b"\x03", b"\x15"):
            self._line = 0
            forward += token
        elif _ESCAPE.match(token) or token == b"\x1b":
            forward += token
        elif self._line + len(token) > self.limit:
            self._refuse(
                out,
                f"line refused: longer than {self.limit} bytes — discarded up to its end, "
                "nothing was run",
                "line",
            )
        else:
            self._line += len(token)
            forward += token

    def _end_paste(self, forward: bytearray, out: Filtered) -> None:
        paste = bytes(self._paste or b"")
        self._paste = None
        lines = paste.replace(b"\r\n", b"\n").strip(b"\r\n")
        if b"\r" in lines or b"\n" in lines:
            count = len(lines.replace(b"\r", b"\n").split(b"\n"))
            out.refused = (
                f"paste refused: {count} lines; the console takes one command at a time "
                "(several commands: put them in a sequence file and 'run' it)"
            )
            return
        if self._line + len(lines) > self.limit:
            out.refused = f"paste refused: the line would be longer than {self.limit} bytes"
            return
        self._line += len(lines)
        forward += PASTE_START + lines + PASTE_END


class KeyGuard:
    """The thread that reads the keys (``fd``: the terminal in raw mode, or the pipe the native
    key reader passes the terminal's bytes on to) and acts on :class:`KeyFilter`'s verdicts:
    ``after_read()`` first (the native reader has sent a panic already: pick up what it did),
    then ``on_panic()`` for a panic key, ``on_interrupt()``, ``on_refused(message, clear_line)``,
    and the rest written to ``forward_fd`` (non-blocking: input the prompt cannot take is
    dropped, never waited for). ``on_end()`` when the input ends (the terminal is gone)."""

    def __init__(
        self,
        fd: int,
        forward_fd: int,
        busy: Callable[[], bool],
        on_panic: Callable[[], None],
        on_interrupt: Callable[[], None],
        on_refused: Callable[[str, bool], None],
        on_end: Callable[[], None],
        key_filter: KeyFilter | None = None,
        after_read: Callable[[], object] | None = None,
    ) -> None:
        self.fd = fd
        self.forward_fd = forward_fd
        self.filter = key_filter or KeyFilter()
        self._busy = busy
        self._on_panic = on_panic
        self._on_interrupt = on_interrupt
        self._on_refused = on_refused
        self._on_end = on_end
        self._after_read = after_read
        os.set_blocking(forward_fd, False)
        self._wake_r, self._wake_w = os.pipe()
        self._thread = threading.Thread(target=self._run, name="ether_ros-keys", daemon=True)

    def start(self) -> None:
        self._thread.start()

    def stop(self) -> None:
        with contextlib.suppress(OSError):
            os.write(self._wake_w, b"x")
        self._thread.join(timeout=2)
        for fd in (self._wake_r, self._wake_w):
            with contextlib.suppress(OSError):
                os.close(fd)

    def _run(self) -> None:
        while True:
            timeout = QUIET_S if self.filter.discarding else None
            try:
                ready, _, _ = select.select([self.fd, self._wake_r], [], [], timeout)
            except OSError:
                break
            if self._wake_r in ready:
                return
            if not ready:
                self.filter.quiet()
                continue
            try:
                data = os.read(self.fd, READ_CHUNK)
            except OSError:  # EIO: the terminal hung up
                data = b""
            if not data:
                break
            self.handle(data)
        self._on_end()

    def handle(self, data: bytes) -> None:
        if self._after_read is not None:
            self._after_read()
        verdict = self.filter.feed(data, self._busy())
        if verdict.panic:
            self._on_panic()
        if verdict.interrupt:
            self._on_interrupt()
        if verdict.refused:
            self._on_refused(verdict.refused, verdict.clear_line)
        if verdict.forward:
            try:
                os.write(self.forward_fd, verdict.forward)
            except BlockingIOError:
                self._on_refused("input dropped: the prompt is not taking it", False)
            except OSError:
                pass  # the prompt is gone
