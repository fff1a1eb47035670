"""Recording, plotting, the experiments and the live view against the simulator in its own
process and network namespace, over a real veth pair, run the way a user runs them."""

from __future__ import annotations

import asyncio
from pathlib import Path

import pytest

from ether_ros.tools.recording import read_recording
from user_commands import LAELAPS, ether_ros

pytestmark = pytest.mark.netns


def test_record_then_plot(sim_iface: str, tmp_path: Path) -> None:
    out_file = tmp_path / "run.mcap"
    out = ether_ros(
        "record", str(LAELAPS), "--interface", sim_iface, "--seconds", "1.5", "-o", str(out_file)
    )
    assert out.returncode == 0, out.stderr
    rec = read_recording(out_file)
    assert [s.name for s in rec.bus.slaves] == [
        "hind_right_leg",
        "hind_left_leg",
        "front_left_leg",
        "front_right_leg",
    ]
    cycles = rec.timing["cycle"]
    assert cycles.size > 100
    assert int(cycles[-1]) - int(cycles[0]) + 1 == cycles.size  # no cycle missing
    assert rec.inputs["front_right_leg"].cycle.size > 10
    assert rec.metadata["command"] == "record"

    plots = tmp_path / "plots"
    out = ether_ros("plot", str(out_file), "-o", str(plots), "--format", "png")  # SVG: unit tests
    assert out.returncode == 0, out.stderr
    names = sorted(p.name for p in plots.iterdir())
    assert "fig6_5_toe_trajectory.png" in names and "loop_timing.png" in names
    assert len(names) == 8


def test_trot_experiment_records_the_ramps(sim_iface: str, tmp_path: Path) -> None:
    out_file = tmp_path / "trot.mcap"
    out = ether_ros(
        "experiment",
        "trot",
        str(LAELAPS),
        "--interface",
        sim_iface,
        "--record",
        str(out_file),
        "--transition",
        "1",
        "--hold",
        "1",
    )
    assert out.returncode == 0, out.stderr
    assert "trot done" in out.stdout
    rec = read_recording(out_file)
    a = rec.outputs["hind_right_leg"]["a_ellipse100"]
    b = rec.outputs["hind_right_leg"]["b_ellipse100"]
    assert a.max() == 5 and b.max() == 4 and a[-1] == 0 and b[-1] == 0
    knee = rec.inputs["hind_right_leg"]["knee_angle"] / 100
    assert knee.max() - knee.min() > 5  # degrees: the simulated leg stepped


def test_frequency_experiment_prints_the_table(sim_iface: str) -> None:
    out = ether_ros(
        "experiment",
        "frequency",
        str(LAELAPS),
        "--interface",
        sim_iface,
        "--from-us",
        "400",
        "--step-us",
        "100",
        "--to-us",
        "300",
        "--round-seconds",
        "1",
    )
    assert out.returncode == 0, out.stderr
    rows = [line.split() for line in out.stdout.splitlines() if line[:14].strip().isdigit()]
    assert [r[:2] for r in rows] == [["400", "2.500"], ["300", "3.333"]]
    assert all(int(r[2]) > 100 for r in rows)  # cycles counted in each round
    assert "shortest loop time" in out.stdout or "no round ran" in out.stdout


def test_top_on_a_standalone_bus(sim_iface: str) -> None:
    from textual.widgets import DataTable, Static

    from ether_ros.master.bus import Bus
    from ether_ros.tools.live import BusLiveSource, TopApp

    bus = Bus.open(str(LAELAPS), interface=sim_iface)
    bus.start()

    async def run() -> None:
        app = TopApp(BusLiveSource(bus), interval=3600)  # refreshed by hand below
        async with app.run_test(size=(150, 40)) as pilot:
            await asyncio.sleep(0.5)  # let cycles run
            app.refresh_view()
            await pilot.pause()
            table = app.query_one("#slaves", DataTable)
            rows = [table.get_row(str(p)) for p in range(4)]
            assert [r[1] for r in rows] == [
                "hind_right_leg",
                "hind_left_leg",
                "front_left_leg",
                "front_right_leg",
            ]
            assert {r[2] for r in rows} == {"OP"}
            stats = str(app.query_one("#stats", Static).content)
            assert "bus laelaps_ii" in stats and "cycles 0 " not in stats
            timing = str(app.query_one("#timing", Static).content)
            assert "round trip" in timing and "no data" not in timing

    try:
        asyncio.run(run())
    finally:
        bus.close()  # TopApp closed it already on unmount; closing twice is harmless
