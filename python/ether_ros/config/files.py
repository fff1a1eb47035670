"""Reading the files a user names (bus configurations, sequence files): regular files only, and
never more than a limit.

``Path.read_text`` on a FIFO waits forever for a writer, on ``/dev/urandom`` or ``/dev/zero`` it
reads until memory runs out. Here the file is opened without blocking, checked to be a regular
file on the descriptor that is then read (so nothing can be swapped in between), and read up to
its limit; every failure is one :class:`ConfigError` line naming the file.
"""

from __future__ import annotations

import os
import stat
from pathlib import Path

from ether_ros.errors import ConfigError

#: Longest path accepted for a file named in a configuration (Linux PATH_MAX).
MAX_PATH_CHARS = 4096

_CHUNK = 1 << 16


def read_regular(path: Path, limit: int, what: str) -> bytes:
    """The bytes of the regular file ``path``, at most ``limit`` of them. ``what`` names the
    kind of file in the errors ("bus configuration", "sequence file")."""
    text = str(path)
    if "\x00" in text or len(text) > MAX_PATH_CHARS:
        raise ConfigError(f"{text[:80]!r}: not a usable file name for a {what}")
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_CLOEXEC)
    except FileNotFoundError:
        raise ConfigError(f"{path}: {what} not found") from None
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read the {what}: {exc.strerror}") from None
    try:
        mode = os.fstat(fd).st_mode
        if not stat.S_ISREG(mode):
            kind = "a directory" if stat.S_ISDIR(mode) else "not a regular file"
            raise ConfigError(f"{path}: {kind}; a {what} must be a regular file")
        chunks: list[bytes] = []
        total = 0
        while True:
            chunk = os.read(fd, _CHUNK)
            if not chunk:
                return b"".join(chunks)
            total += len(chunk)
            if total > limit:
                raise ConfigError(f"{path}: longer than a {what} may be ({limit} bytes)")
            chunks.append(chunk)
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read the {what}: {exc.strerror}") from None
    finally:
        os.close(fd)


def read_text(path: Path, limit: int, what: str) -> str:
    """:func:`read_regular` decoded as UTF-8 (a BOM is allowed)."""
    data = read_regular(path, limit, what)
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise ConfigError(
            f"{path}: not UTF-8 text (byte {exc.start}: {data[exc.start : exc.start + 1]!r})"
        ) from None
