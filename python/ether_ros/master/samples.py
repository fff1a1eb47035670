"""Per-cycle samples of the engine's real-time thread, as numpy arrays.

``Engine.drain_samples(n)`` returns two byte strings: fixed 56-byte records (one per cycle, layout
below, little endian) and, for each record, a copy of the whole process image of that cycle
(inputs as received, outputs as sent). :func:`decode_samples` turns them into a structured array
and a 2-D ``uint8`` array without copying. The layout is the Rust ``SampleRecord::encode`` in
``crates/engine/src/handover.rs``; the unit tests check both sides agree.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

#: One record: what the RT thread saw in one cycle.
SAMPLE_DTYPE = np.dtype(
    [
        ("cycle", "<u8"),  # cycle number since start_cyclic
        ("t_wake_ns", "<u8"),  # actual wake-up, CLOCK_MONOTONIC
        ("wake_latency_ns", "<i8"),  # actual minus planned wake-up
        ("exec_ns", "<u4"),  # wake-up to cyclic frame sent
        ("period_ns", "<u4"),  # since the previous wake-up (0 in the first cycle)
        ("rtt_ns", "<u4"),  # round trip of the reply processed this cycle (0: none)
        ("wkc", "<u2"),  # sum of the logical datagrams' working counters of the replies
        ("flags", "<u2"),  # FLAG_* bits
        ("dc_diff_ns", "<i4"),  # see docs/engine.md, "Distributed clocks"
        ("lost_mask", "<u4"),  # bit k: cyclic frame k's reply declared lost this cycle
        # bit k: cyclic frame k's inputs in this image are stale (no reply came back whole within
        # two of its periods, or none yet)
        ("stale_mask", "<u4"),
        ("reserved", "<u4"),
    ]
)
RECORD_LEN = SAMPLE_DTYPE.itemsize  # 56

#: The reply to the cyclic frame did not arrive in time.
FLAG_LOST = 1 << 0
#: A reply to an older cyclic frame arrived late (and was ignored).
FLAG_LATE = 1 << 1
#: An LRW working counter differed from the expected one.
FLAG_WKC_ERROR = 1 << 2
#: Panic latched: the safe image was on the wire.
FLAG_PANIC = 1 << 3
#: Command watchdog expired: the safe image was on the wire.
FLAG_WATCHDOG = 1 << 4
#: A frame matching nothing we sent arrived (and was ignored).
FLAG_UNMATCHED = 1 << 5
#: The DC controller moved the master's wake-up (master_follows_ref).
FLAG_DC_ADJUSTED = 1 << 6
#: An acyclic (mailbox) frame was sent after the cyclic frame.
FLAG_ACYCLIC = 1 << 7
#: The thread woke a cycle or more late: cycles were skipped.
FLAG_OVERRUN = 1 << 8
#: Sending the cyclic frame failed (link down, no buffer space).
FLAG_SEND_ERROR = 1 << 9

#: Flag names by bit, the same names as ``ether_ros._native.SAMPLE_FLAGS``.
FLAGS: dict[str, int] = {
    "lost": FLAG_LOST,
    "late": FLAG_LATE,
    "wkc_error": FLAG_WKC_ERROR,
    "panic": FLAG_PANIC,
    "watchdog": FLAG_WATCHDOG,
    "unmatched": FLAG_UNMATCHED,
    "dc_adjusted": FLAG_DC_ADJUSTED,
    "acyclic": FLAG_ACYCLIC,
    "overrun": FLAG_OVERRUN,
    "send_error": FLAG_SEND_ERROR,
}


@dataclass(frozen=True)
class Samples:
    """Decoded samples: ``records[i]`` belongs to ``images[i]``."""

    records: npt.NDArray[np.void]
    images: npt.NDArray[np.uint8]

    def __len__(self) -> int:
        return len(self.records)


def decode_samples(records: bytes, images: bytes, image_len: int | None = None) -> Samples:
    """Turn ``Engine.drain_samples`` output into arrays. ``image_len`` defaults to what the
    sizes imply; a mismatch is a ``ValueError`` saying which sizes disagree."""
    if len(records) % RECORD_LEN:
        raise ValueError(f"sample records are {len(records)} bytes, not a multiple of {RECORD_LEN}")
    n = len(records) // RECORD_LEN
    if image_len is None:
        image_len = len(images) // n if n else 0
    if len(images) != n * image_len:
        raise ValueError(
            f"{n} sample records need {n * image_len} image bytes ({image_len} each), "
            f"got {len(images)}"
        )
    recs = np.frombuffer(records, dtype=SAMPLE_DTYPE, count=n)
    imgs = np.frombuffer(images, dtype=np.uint8).reshape(n, image_len)
    return Samples(recs, imgs)


def flag_names(flags: int) -> list[str]:
    """The names of the bits set in one record's ``flags``."""
    return [name for name, bit in FLAGS.items() if flags & bit]


def count_flags(records: npt.NDArray[np.void]) -> dict[str, int]:
    """How many records carry each flag."""
    f = records["flags"]
    return {name: int(np.count_nonzero(f & bit)) for name, bit in FLAGS.items()}
