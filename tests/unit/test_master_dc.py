"""DC arithmetic: loop times, line delays, offsets, SYNC0 start time, AssignActivate bytes."""

from __future__ import annotations

import pytest

from ether_ros.master.dc import (
    MASK64,
    assign_activate_bytes,
    decode_time_diff,
    diff32,
    line_delays,
    loop_times,
    sync0_start_time,
    system_time_offsets,
)


def test_diff32_handles_wraparound() -> None:
    assert diff32(10, 5) == 5
    assert diff32(3, 0xFFFF_FFFE) == 5


def test_line_of_four_gives_cumulative_half_loop_differences() -> None:
    # Frame enters each slave at port 0 and comes back at port 1; each hop (cable + pass-through)
    # is 700 ns one way, the last slave turns the frame round internally.
    hop = 700
    n = 4
    port0 = [1000 + i * hop for i in range(n)]
    # back at slave i after going down and back through the rest of the line
    port1 = [port0[i] + 2 * hop * (n - 1 - i) for i in range(n)]
    loops = loop_times(port0, port1, [i < n - 1 for i in range(n)])
    assert loops == [4200, 2800, 1400, 0]
    assert line_delays(loops) == [0, 700, 1400, 2100]


def test_loop_time_uses_32bit_wrap_and_last_slave_is_zero() -> None:
    loops = loop_times([0xFFFF_FF00, 50], [0x0000_0100, 999], [True, False])
    assert loops == [0x200, 0]


def test_offsets_make_every_system_time_equal_to_master_plus_delay() -> None:
    master = 1_000_000_000_000
    local = [5, 123_456_789, 2**63 + 7]
    delays = [0, 700, 1400]
    offsets = system_time_offsets(master, local, delays)
    for t, d, o in zip(local, delays, offsets, strict=True):
        assert (t + o) & MASK64 == master + d


def test_sync0_start_is_aligned_to_the_cycle_plus_shift_with_margin() -> None:
    cycle, shift, margin = 400_000, 55_000, 100_000_000
    now = 1_234_567_891
    start = sync0_start_time(now, cycle, shift, margin)
    assert (start - shift) % cycle == 0
    assert start - shift >= now + margin
    assert start - shift < now + margin + cycle
    with pytest.raises(ValueError):
        sync0_start_time(now, 0, 0, 0)


def test_assign_activate_low_byte_is_unit_control_high_byte_activation() -> None:
    assert assign_activate_bytes(0x0300) == (0x00, 0x03)
    assert assign_activate_bytes(0x0700) == (0x00, 0x07)
    assert assign_activate_bytes(0x0001) == (0x01, 0x00)


def test_time_difference_sign_bit() -> None:
    assert decode_time_diff(0x0000_0010) == 16
    assert decode_time_diff(0x8000_0010) == -16
