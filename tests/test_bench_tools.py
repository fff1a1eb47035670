"""The benchmark tools themselves: the cyclictest parser and the C echo/round-trip pair over a
real veth pair (nothing faked). Timing is never asserted, only behaviour."""

from __future__ import annotations

import socket
import sys
from pathlib import Path

import pytest

from ether_ros.testing.netns import VethPair

BENCH = Path(__file__).resolve().parent.parent / "bench"
sys.path.insert(0, str(BENCH))

from baseline import (  # noqa: E402
    ToolError,
    echo_responder,
    parse_cyclictest,
    rtt_probe,
)

CYCLICTEST_OUTPUT = """# /dev/cpu_dma_latency set to 0us
# Histogram
000000 000000
000001 000000
000002 000010
000003 000080
000004 000009
000005 000000
000006 000001
# Total: 000000100
# Min Latencies: 00002
# Avg Latencies: 00003
# Max Latencies: 00006
# Histogram Overflows: 00000
# Histogram Overflow at cycle number:
# Thread 0:
"""


def test_cyclictest_histogram_percentiles() -> None:
    h = parse_cyclictest(CYCLICTEST_OUTPUT)
    assert h.total == 100
    assert (h.min_us, h.avg_us, h.max_us) == (2, 3, 6)
    assert h.percentile(5) == 2
    assert h.percentile(50) == 3
    assert h.percentile(95) == 4
    assert h.percentile(100) == 6


def test_cyclictest_overflows_count_as_the_maximum() -> None:
    out = CYCLICTEST_OUTPUT.replace("Max Latencies: 00006", "Max Latencies: 02500").replace(
        "Histogram Overflows: 00000", "Histogram Overflows: 00100"
    )
    h = parse_cyclictest(out)
    assert h.total == 200
    assert h.percentile(99) == 2500


def test_cyclictest_garbage_is_refused() -> None:
    with pytest.raises(ToolError, match="Max Latencies"):
        parse_cyclictest("something else entirely\n")


def _lrw_frame(index: int, data: bytes) -> bytes:
    dg = bytes([0x0C, index, 0, 0, 0, 0]) + len(data).to_bytes(2, "little") + b"\0\0"
    dg += data + (7).to_bytes(2, "little")  # working counter starts at 7
    ecat = (len(dg) | 0x1000).to_bytes(2, "little") + dg
    return b"\xff" * 6 + b"\x01" * 6 + b"\x88\xa4" + ecat


def test_c_echo_bumps_the_working_counter_and_marks_the_source(veth_ns: VethPair) -> None:
    with echo_responder(veth_ns.slave, netns=veth_ns.netns):
        # Protocol 0 until bound: nothing from other interfaces is queued before bind().
        s = socket.socket(socket.AF_PACKET, socket.SOCK_RAW, 0)
        s.bind((veth_ns.master, 0x88A4))
        s.settimeout(2.0)
        sent = _lrw_frame(0x5A, bytes(range(20)))
        s.send(sent)
        while True:
            reply = s.recv(2048)
            if reply[6] & 0x02:
                break
        s.close()
    assert reply[6] == 0x03 and reply[7:12] == b"\x01" * 5
    assert reply[17] == 0x5A  # datagram index unchanged
    body = reply[14 + 2 + 10 : 14 + 2 + 10 + 20]
    assert body == bytes(range(20))
    assert int.from_bytes(reply[14 + 2 + 10 + 20 : 14 + 2 + 10 + 22], "little") == 8


def test_rtt_probe_counts_every_answer_from_the_echo(veth_ns: VethPair) -> None:
    with echo_responder(veth_ns.slave, netns=veth_ns.netns):
        pingpong = rtt_probe(veth_ns.master, frames=300, warmup=10)
        paced = rtt_probe(veth_ns.master, rate_hz=2000, frames=200, warmup=10)
    assert pingpong.sent == 310 and pingpong.answered == 310 and pingpong.lost == 0
    assert paced.sent == 210 and paced.answered == 210
    for r in (pingpong, paced):
        q = r.rtt_ns
        assert 0 < q["min"] <= q["p50"] <= q["p99"] <= q["max"]


def test_rtt_probe_reports_losses_without_a_responder(veth: VethPair) -> None:
    r = rtt_probe(veth.master, frames=5, warmup=0, timeout_us=2000)
    assert r.sent == 5 and r.answered == 0 and r.lost == 5


def test_first_frames_matches_each_command_to_the_first_frame_sent_after_it() -> None:
    from bench_ros import Sent, first_frames

    sent = [Sent(seq, 1000 + seq, 0, 100 * seq, 100 * seq + 5) for seq in range(1, 5)]
    changes = [
        (50, 1001),  # carries command 1's value before command 1 was published: not its frame
        (120, 1001),  # command 1 on the wire
        (330, 1003),  # command 2 was replaced by 3 before any frame carried it
        (900, 1099),  # a value nobody sent
    ]
    frames = first_frames(sent, changes)
    assert frames == {1: (120, False), 2: (330, True), 3: (330, False)}  # 4 never reached it


def test_start_cycles_finds_each_joints_first_move_and_the_skew() -> None:
    import numpy as np

    from bench_trajectory import start_cycles

    cycles = np.array([100, 101, 102, 103, 105, 106])  # 104 missing from the recording
    targets = np.array(
        [
            [7, -3, 0],
            [7, -3, 0],
            [8, -3, 0],  # joint 0 leaves its start at cycle 102
            [9, -4, 0],  # joint 1 at 103
            [10, -5, 1],  # joint 2 seen at 105, but 104 was not recorded
            [7, -3, 0],  # back at the start later: still started
        ]
    )
    s = start_cycles(cycles, targets)
    assert s.cycles == [102, 103, 105]
    assert s.exact == [True, True, False]
    assert s.skew == 3
    with pytest.raises(ValueError, match="joint 1: its target never leaves -3"):
        start_cycles(cycles[:3], targets[:3])


def test_tracking_is_rms_and_max_of_the_absolute_error_per_joint_and_overall() -> None:
    import numpy as np

    from bench_trajectory import tracking, trajectory

    t = tracking(np.array([[3.0, 0.0], [-4.0, 0.0], [0.0, 1.0], [0.0, -1.0]]))
    assert t.rms == pytest.approx([2.5, np.sqrt(0.5)])
    assert t.max == [4.0, 1.0]
    assert t.rms_all == pytest.approx(np.sqrt(27 / 8))
    assert t.max_all == 4.0 and t.samples == 4
    assert 3.0 < t.p99_all <= 4.0  # between the two largest |errors|
    # The benchmark's trajectory: within ±0.9 rad, from rest at 0 (its first point, at time 0),
    # moving from the next point on, at rest at 0 at the end.
    track = trajectory(3.0)
    assert len(track) == 6 and all(len(p) == 301 for p in track.values())
    for points in track.values():
        assert max(abs(p) for _, p, _ in points) <= 0.9
        assert points[0] == (0.0, 0.0, 0.0) and points[1][1] != 0.0
        assert points[-1] == (3.0, 0.0, 0.0)
    # Every joint leaves its start at the same speed (the start cycles compare).
    first = [abs(points[1][1]) for points in track.values()]
    assert max(first) - min(first) < 1e-3 * max(first)


def test_unwrap_counts_cycles_from_frame_numbers_modulo_128() -> None:
    from bench_trajectory import unwrap

    # 126, 127, 0 (wrapped), 2 (one frame not captured), 2 again (a whole turn later)
    assert unwrap([126, 127, 0, 2, 2], 128).tolist() == [0, 1, 2, 4, 132]
