"""Slave groups in the command-line tools' output: `ether-ros slaves` and `ether-ros bench
cycle` (their formatting, from the data the bus gives them)."""

from __future__ import annotations

from ether_ros.cli.bench import format_result, summarize
from ether_ros.cli.slaves import details, line


def test_slaves_line_names_the_group_and_lrw_support() -> None:
    entry = {
        "position": 3, "station": 0x1004, "state": "OP", "error": False, "vendor_id": 0xA12,
        "product_code": 0x20002, "name": "ServoDrive2", "configured_name": "drive_00",
        "group": "fast", "alias": 0, "revision": 1, "serial": 2, "esc_type": 0x11, "dc": True,
        "lrw": False, "al_status_code": 0,
        "mailbox": {"rx": [0x1000, 128], "tx": [0x1080, 128], "protocols": 4},
        "rx_pdos": [], "tx_pdos": [],
    }  # fmt: skip
    assert line(entry).endswith("ServoDrive2 (drive_00) [group fast]")
    assert "LRW no (LRD + LWR)" in details(entry)[0]
    assert "[group" not in line(entry | {"group": None})


def test_bench_cycle_reports_each_group() -> None:
    stats = {
        "cycles": 4000, "lost_frames": 3, "frames": [{}, {}, {}],
        "groups": [
            {"name": "default", "every": 1, "cycle_ns": 250_000, "frames": [0, 1], "sent": 4000,
             "lost": 3, "late": 1, "wkc_errors": 0, "watchdog_trips": 0, "expected_wkc": 30,
             "last_wkc": 30},
            {"name": "io", "every": 8, "cycle_ns": 2_000_000, "frames": [2], "sent": 500,
             "lost": 0, "late": 0, "wkc_errors": 2, "watchdog_trips": 0, "expected_wkc": 9,
             "last_wkc": 9},
        ],
    }  # fmt: skip
    result = summarize(stats, 1.0, 250)
    assert result["frames"] == 3
    text = format_result(result)
    assert "group default: cycle 250 µs, frames [0, 1], 4000 sent, 3 lost, 1 late" in text
    assert "group io: cycle 2000 µs, frames [2], 500 sent, 0 lost, 0 late, 2 WKC errors" in text
