"""A command on a pseudo-terminal, driven as an operator would: keys written to the terminal,
the screen read back as text. For the tests and benchmarks of the interactive tools (console,
``top``).

The program gets the pty's slave side as stdin, stdout and stderr, in a session of its own; a
thread collects everything it writes. :meth:`Pty.text` is
that output with the terminal's escape sequences taken out, for matching.
"""

from __future__ import annotations

import contextlib
import fcntl
import os
import re
import signal
import struct
import subprocess
import termios
import threading
import time
from collections.abc import Mapping, Sequence
from types import TracebackType

# CSI, OSC and two-byte escapes; what remains is the text a reader sees (roughly).
_ESCAPES = re.compile(rb"\x1b\[[0-9;?<=>]*[ -/]*[@-~]|\x1b\][^\x07\x1b]*(\x07|\x1b\\)|\x1b[@-_]")

CTRL_C = b"\x03"
CTRL_P = b"\x10"
F1 = b"\x1bOP"


class Pty:
    def __init__(
        self,
        argv: Sequence[str],
        env: Mapping[str, str] | None = None,
        rows: int = 50,
        cols: int = 160,
    ) -> None:
        master, slave = os.openpty()
        fcntl.ioctl(slave, termios.TIOCSWINSZ, struct.pack("HHHH", rows, cols, 0, 0))
        self.master = master
        self.proc = subprocess.Popen(
            list(argv),
            stdin=slave,
            stdout=slave,
            stderr=slave,
            env=dict(env) if env is not None else None,
            start_new_session=True,  # its own process group: close() ends all of it
            close_fds=True,
        )
        os.close(slave)
        self._raw = bytearray()
        self._lock = threading.Lock()
        self._changed = threading.Condition(self._lock)
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        while True:
            try:
                data = os.read(self.master, 65536)
            except OSError:  # EIO: the program closed the terminal
                data = b""
            with self._changed:
                if not data:
                    self._changed.notify_all()
                    return
                self._raw += data
                self._changed.notify_all()

    def write(self, data: bytes) -> None:
        """Keys, as typed: all of ``data``, however long (the terminal takes it in parts)."""
        view = memoryview(data)
        while view:
            n = os.write(self.master, view)
            view = view[n:]

    def raw(self) -> bytes:
        with self._lock:
            return bytes(self._raw)

    def text(self) -> str:
        """Everything written so far, without escape sequences, ``\\r`` taken out."""
        return _ESCAPES.sub(b"", self.raw()).replace(b"\r", b"").decode(errors="replace")

    def mark(self) -> int:
        """A position in :meth:`text`, to look only at what comes after it."""
        return len(self.text())

    def expect(self, pattern: str, timeout: float = 30.0, since: int = 0) -> re.Match[str]:
        """Wait until ``pattern`` (a regular expression) shows in the text after ``since``;
        AssertionError with the end of the screen when it does not within ``timeout`` s."""
        regex = re.compile(pattern)
        deadline = time.monotonic() + timeout
        with self._changed:
            while True:
                text = _ESCAPES.sub(b"", bytes(self._raw)).replace(b"\r", b"")
                found = regex.search(text.decode(errors="replace"), since)
                if found:
                    return found
                left = deadline - time.monotonic()
                if left <= 0:
                    tail = text.decode(errors="replace")[-1500:]
                    raise AssertionError(f"{pattern!r} did not show within {timeout:g} s:\n{tail}")
                self._changed.wait(min(left, 0.2))

    def wait(self, timeout: float = 30.0) -> int:
        return self.proc.wait(timeout)

    def close(self) -> None:
        if self.proc.poll() is None:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(self.proc.pid, signal.SIGTERM)
            try:
                self.proc.wait(10)
            except subprocess.TimeoutExpired:
                with contextlib.suppress(ProcessLookupError):
                    os.killpg(self.proc.pid, signal.SIGKILL)
                self.proc.wait()
        with contextlib.suppress(OSError):
            os.close(self.master)
        self._reader.join(2)

    def __enter__(self) -> Pty:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()
