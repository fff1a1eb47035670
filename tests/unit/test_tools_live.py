"""`ether-ros top`: the screen driven by textual's pilot, fed by a source one layer down."""

from __future__ import annotations

import asyncio

import numpy as np
import pytest
from textual.widgets import DataTable, Static

from ether_ros.tools.live import (
    LiveSnapshot,
    SlaveRow,
    StaticSource,
    TopApp,
    histogram_text,
    snapshot_from_diagnostics,
    stats_text,
    timing_text,
)


def snapshot(lost: int, state: str) -> LiveSnapshot:
    rng = np.random.default_rng(1)
    return LiveSnapshot(
        bus="laelaps_ii",
        cycle_us=400,
        cycles=25_000,
        lost_frames=lost,
        late_frames=1,
        wkc_errors=0,
        dc_sync_error_ns=87.0,
        slaves=[
            SlaveRow(0, "front_left", state, "LaelapsII_Leg"),
            SlaveRow(1, "front_right", "OP", "LaelapsII_Leg"),
        ],
        wake_latency_us=list(rng.gamma(2.0, 5.0, 500)),
        exec_us=[20.0] * 500,
        period_us=list(400 + rng.normal(0, 3, 500)),
        rtt_us=[110.0] * 500,
        source="test",
    )


def text_of(app: TopApp, widget_id: str) -> str:
    return str(app.query_one(widget_id, Static).content)


def test_screen_shows_slaves_stats_and_histograms_and_updates() -> None:
    source = StaticSource([snapshot(0, "SAFEOP"), snapshot(3, "OP")])

    async def run() -> None:
        app = TopApp(source, interval=3600)  # refreshed by hand below: no timing involved
        async with app.run_test(size=(140, 40)) as pilot:
            await pilot.pause()
            stats = text_of(app, "#stats")
            assert "bus laelaps_ii" in stats and "2500 Hz" in stats
            assert "DC sync error 87 ns" in stats
            table = app.query_one("#slaves", DataTable)
            assert table.row_count == 2
            assert table.get_row("0") == ["0", "front_left", "SAFEOP", "LaelapsII_Leg"]
            timing = text_of(app, "#timing")
            for label in ("wake-up latency", "execution", "period", "round trip"):
                assert label in timing
            assert "median   110.0" in timing
            # The next refresh brings the second snapshot.
            app.refresh_view()
            await pilot.pause()
            assert "lost frames 3" in text_of(app, "#stats")
            assert table.get_row("0")[2] == "OP"
            await pilot.press("q")
        assert source.closed

    asyncio.run(run())


def test_ctrl_p_and_f1_panic_and_the_command_palette_stays_shut() -> None:
    source = StaticSource([snapshot(0, "OP")])

    async def run() -> None:
        app = TopApp(source, interval=3600)
        async with app.run_test(size=(140, 40)) as pilot:
            await pilot.pause()
            await pilot.press("ctrl+p")
            await pilot.press("f1")
            await pilot.pause()
            assert source.panics == 2
            assert len(app.screen_stack) == 1  # no command palette on top of the view
            assert "PANIC (static source, 2)" in text_of(app, "#message")

    asyncio.run(run())


def test_a_failing_source_is_shown_not_raised() -> None:
    class Broken:
        def poll(self) -> LiveSnapshot:
            raise RuntimeError("node went away")

        def close(self) -> None:
            pass

    async def run() -> None:
        app = TopApp(Broken(), interval=3600)
        async with app.run_test() as pilot:
            await pilot.pause()
            assert "source: node went away" in text_of(app, "#stats")

    asyncio.run(run())


def test_histogram_text_marks_the_tail() -> None:
    line = histogram_text("period", [400.0] * 999 + [900.0])
    bars = line.split("|")[1]
    assert bars[0] == "█" and bars[-1] != " "  # the single late cycle still shows
    assert "max   900.0" in line
    assert "no data" in histogram_text("round trip", [])


def test_snapshot_from_the_nodes_diagnostics_shows_quantiles() -> None:
    master = {
        "lifecycle_state": "active",
        "cycles": "25000",
        "lost_frames": "7",
        "late_frames": "1",
        "wkc_errors": "0",
        "panic": "true",
        "rtt_p50_ns": "110000",
        "rtt_p99_ns": "130000",
        "rtt_max_ns": "150000",
        "dc_sync_error_max_ns": "-12",
    }
    slaves = {
        "hind_left_leg": ("OP", {"position": "1", "al_state": "OP", "al_error": "false"}),
        "hind_right_leg": (
            "SAFEOP with error 0x001b: sync manager watchdog",
            {"position": "0", "al_state": "SAFEOP", "al_error": "true"},
        ),
    }
    snap = snapshot_from_diagnostics(master, slaves, "ether_comm")
    assert [(r.name, r.state) for r in snap.slaves] == [
        ("hind_right_leg", "SAFEOP ERR"),
        ("hind_left_leg", "OP"),
    ]
    assert "watchdog" in snap.slaves[0].detail
    assert snap.lost_frames == 7 and snap.dc_sync_error_ns == -12.0 and snap.panic
    text = timing_text(snap)
    assert "round trip       p50    110.0  p99    130.0  max    150.0 µs" in text
    assert "execution        no data" in text


def test_groups_from_the_nodes_diagnostics_are_shown() -> None:
    from diagnostic_msgs.msg import DiagnosticStatus

    from ether_ros.master.groups import GroupStats
    from ether_ros.ros.diagnostics import group_statuses, values_of

    groups = [GroupStats("io", 4, 4_000_000, ("io_a",), (2,), 3, 0, 250, 1, 0, 40)]
    (status,) = group_statuses("ether_comm", groups)
    assert (
        status.level == DiagnosticStatus.ERROR and status.message == "working counter 0, expected 3"
    )
    snap = snapshot_from_diagnostics({"cycles": "1"}, {}, "b", groups={"io": values_of(status)})
    text = stats_text(snap)
    assert "group io: every 4000 µs   lost 1   late 0   WKC errors 40   WKC 0/3" in text


@pytest.mark.ros
def test_diagnostics_source_reads_the_nodes_statuses() -> None:
    """A real rclpy publisher sends what the node's diagnostics module builds; the live view's
    source subscribes and turns it into a snapshot."""
    import time
    import uuid
    from types import SimpleNamespace

    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray

    from ether_ros.ros import diagnostics
    from ether_ros.ros.top_source import DiagnosticsLiveSource

    topic = f"/test_diag_{uuid.uuid4().hex[:8]}"
    source = DiagnosticsLiveSource(topic)
    node = rclpy.create_node(f"test_pub_{uuid.uuid4().hex[:8]}")
    try:
        pub = node.create_publisher(DiagnosticArray, topic, 10)
        stats = {
            "cycles": 5000,
            "lost_frames": 2,
            "rtt.p50": 110000,
            "rtt.p99": 120000,
            "rtt.max": 150000,
        }
        states = [
            SimpleNamespace(
                name="hind_right_leg",
                position=0,
                station=0x1001,
                state="OP",
                error=False,
                code=0,
                text="",
            ),
            SimpleNamespace(
                name="hind_left_leg",
                position=1,
                station=0x1002,
                state="SAFEOP",
                error=True,
                code=0x1B,
                text="sync manager watchdog",
            ),
        ]
        statuses = [
            diagnostics.master_status("ether_comm", "active", stats, {}, False, 42.0),
            *diagnostics.slave_statuses("ether_comm", states),
        ]
        msg = diagnostics.array(statuses, node.get_clock().now().to_msg())
        deadline = time.monotonic() + 10
        snap = source.poll()
        while snap.error and time.monotonic() < deadline:
            pub.publish(msg)
            time.sleep(0.05)
            snap = source.poll()
        assert not snap.error, snap.error
        assert snap.source.startswith("node test_pub_") or snap.source.startswith("node ")
        assert snap.cycles == 5000 and snap.lost_frames == 2
        assert snap.dc_sync_error_ns == 42.0
        assert [(r.name, r.state) for r in snap.slaves] == [
            ("hind_right_leg", "OP"),
            ("hind_left_leg", "SAFEOP ERR"),
        ]
        assert snap.quantiles_us["rtt"] == (110.0, 120.0, 150.0)
        assert not snap.stale
        # The node stops reporting (it died): after two of its periods the view says so, and
        # no slave is shown in the state of its last report.
        deadline = time.monotonic() + 30
        while not snap.stale and time.monotonic() < deadline:
            time.sleep(0.05)
            snap = source.poll()
        assert "the node is gone or stalled" in snap.stale
        assert [r.state for r in snap.slaves] == ["?", "?"]
        assert stats_text(snap).startswith("STALE: no report from node")
    finally:
        node.destroy_node()
        source.close()


def test_axes_from_the_diagnostics() -> None:
    """The node's per-axis statuses become top's axis rows: state, mode, position and the
    error with its text (the last fault when the drive recovered from it)."""
    from ether_ros.tools.live import axes_text

    axes = {
        "elbow": {"state": "fault", "mode": "csp", "position": "0.25", "error_code": "0x2310",
                  "error_text": "continuous over-current", "last_fault_code": "0x2310"},
        "wrist": {"state": "operation_enabled", "mode": "csv", "position": "-1.5",
                  "error_code": "0x0000", "last_fault_code": "0x7305",
                  "last_fault_text": "incremental encoder 1 fault"},
        "base": {"state": "switch_on_disabled", "mode": "csp", "position": "0",
                 "error_code": "0x0000", "last_fault_code": "0x0000"},
    }  # fmt: skip
    snap = snapshot_from_diagnostics({"cycles": "1"}, {}, "arm6", axes)
    assert [(a.joint, a.state, a.mode, a.position, a.error) for a in snap.axes] == [
        ("elbow", "fault", "csp", 0.25, "0x2310 continuous over-current"),
        ("wrist", "operation_enabled", "csv", -1.5, "0x7305 incremental encoder 1 fault"),
        ("base", "switch_on_disabled", "csp", 0.0, ""),
    ]
    text = axes_text(snap).splitlines()
    assert text[0].split() == ["joint", "state", "mode", "position", "error"]
    assert text[1].split() == ["elbow", "fault", "csp", "0.2500", "0x2310", "continuous",
                               "over-current"]  # fmt: skip
    assert axes_text(snapshot_from_diagnostics({}, {})) == ""


def test_axis_extras_from_the_nodes_joint_extras_are_shown_under_their_axis() -> None:
    """The node's ``joint_extras`` (parallel arrays) become each axis's extras, shown on one
    line under the axis: whole numbers (a digital input word) exactly, the rest to 4 digits;
    an axis without extras has no such line, and a message whose arrays differ in length
    gives no extras rather than a wrong pairing."""
    from types import SimpleNamespace

    from ether_ros.ros.top_source import extras_by_joint
    from ether_ros.tools.live import axes_text

    msg = SimpleNamespace(
        joints=["elbow", "elbow", "elbow"],
        names=["inputs", "outputs", "velocity_offset"],
        values=[float(0x0005_0001), float(0x0005_0000), 0.123456],
    )
    extras = extras_by_joint(msg)
    assert extras == {
        "elbow": {"inputs": 327681.0, "outputs": 327680.0, "velocity_offset": 0.123456}
    }
    axes = {
        name: {"state": "operation_enabled", "mode": "csp", "position": "0",
               "error_code": "0x0000", "last_fault_code": "0x0000"}
        for name in ("shoulder", "elbow")
    }  # fmt: skip
    snap = snapshot_from_diagnostics({"cycles": "1"}, {}, "arm6", axes, extras=extras)
    assert [a.extras for a in snap.axes] == [{}, extras["elbow"]]
    text = axes_text(snap).splitlines()
    assert len(text) == 4  # header, shoulder, elbow, elbow's extras
    assert text[1].split()[0] == "shoulder" and text[2].split()[0] == "elbow"
    assert text[3].split() == ["inputs=327681", "outputs=327680", "velocity_offset=0.1235"]
    msg.values = [1.0, 2.0]
    assert extras_by_joint(msg) == {}
