"""Targets that misbehave on purpose, to check that the fuzz runner
(``ether_ros.testing.fuzzing``) tells a hang, a foreign exception and memory exhaustion apart."""

from __future__ import annotations

import time
from pathlib import Path


def misbehave(path: Path) -> str:
    what = path.read_bytes()
    if what == b"hang":
        time.sleep(3600)
    if what == b"raise":
        raise KeyError("not ours")
    if what == b"memory":
        # More than the worker's address space at once: refused by the kernel, not swapped.
        hog = bytearray(4 * 1024**3)
        return str(len(hog))
    return "fine"
