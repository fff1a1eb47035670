"""The sample record layout of ``master/samples.py`` agrees with the Rust engine's, and the
decoder rejects inconsistent sizes with a clear message."""

from __future__ import annotations

import struct

import numpy as np
import pytest

import ether_ros._native as _native
from ether_ros.master.samples import (
    FLAGS,
    RECORD_LEN,
    SAMPLE_DTYPE,
    count_flags,
    decode_samples,
    flag_names,
)

# The little-endian layout written by SampleRecord::encode in crates/engine/src/handover.rs.
RECORD = struct.Struct("<QQqIIIHHiII4x")


def test_layout_and_flags_match_the_engine() -> None:
    assert RECORD_LEN == RECORD.size == _native.SAMPLE_RECORD_LEN == 56
    assert dict(_native.SAMPLE_FLAGS) == FLAGS


def test_decode_reads_fields_and_images_in_order() -> None:
    rows = [
        (7, 1_000_000, -5, 3_000, 400_000, 90_000, 12, FLAGS["lost"] | FLAGS["panic"], -1234, 1, 3),
        (8, 1_400_000, 17, 2_500, 400_017, 0, 0, 0, 99, 0, 0),
    ]
    records = b"".join(RECORD.pack(*r) for r in rows)
    images = bytes(range(6))
    s = decode_samples(records, images, image_len=3)
    assert len(s) == 2
    names = ["cycle", "t_wake_ns", "wake_latency_ns", "exec_ns", "period_ns", "rtt_ns", "wkc"]
    for row, rec in zip(rows, s.records, strict=True):
        assert tuple(int(rec[n]) for n in names) == row[:7]
        assert int(rec["flags"]) == row[7] and int(rec["dc_diff_ns"]) == row[8]
        assert (int(rec["lost_mask"]), int(rec["stale_mask"])) == row[9:]
    assert s.images.tolist() == [[0, 1, 2], [3, 4, 5]]
    assert flag_names(int(s.records[0]["flags"])) == ["lost", "panic"]
    assert count_flags(s.records)["lost"] == 1
    assert s.records.dtype == SAMPLE_DTYPE


def test_image_length_is_inferred_and_empty_input_is_fine() -> None:
    records = RECORD.pack(1, 2, 3, 4, 5, 6, 7, 8, 9, 0, 0)
    assert decode_samples(records, b"abcd").images.shape == (1, 4)
    empty = decode_samples(b"", b"")
    assert len(empty) == 0 and empty.images.shape == (0, 0)
    assert np.asarray(empty.records).dtype == SAMPLE_DTYPE


def test_inconsistent_sizes_are_value_errors() -> None:
    with pytest.raises(ValueError, match="not a multiple of 56"):
        decode_samples(bytes(55), b"")
    with pytest.raises(ValueError, match="need 8 image bytes"):
        decode_samples(bytes(112), bytes(7), image_len=4)
