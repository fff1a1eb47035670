"""`ether-ros top` on the running node: the simulator and `ether-ros run` in their own
processes over a real veth pair; the live view subscribes to the node's diagnostics."""

from __future__ import annotations

import asyncio
import os
import random
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from ether_ros.sim.proof import SimProcess
from ether_ros.testing.netns import VethPair

pytestmark = [pytest.mark.netns, pytest.mark.ros]

REPO = Path(__file__).resolve().parents[2]
LAELAPS = REPO / "config" / "laelaps.yaml"


def test_top_shows_the_running_nodes_slaves(
    veth_ns: VethPair, monkeypatch: pytest.MonkeyPatch
) -> None:
    import rclpy
    from textual.widgets import DataTable, Static

    from ether_ros.tools.live import DiagnosticsLiveSource, TopApp

    if rclpy.ok():
        pytest.skip("rclpy already initialised in this process (another ROS domain)")
    # A domain of our own: other tests' nodes on this machine must not show up here.
    domain = str(random.randint(100, 200))
    monkeypatch.setenv("ROS_DOMAIN_ID", domain)
    with SimProcess(LAELAPS, veth_ns.slave, veth_ns.netns):
        node = subprocess.Popen(
            [sys.executable, "-m", "ether_ros.cli.main", "run", str(LAELAPS), "-i", veth_ns.master],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            env={**os.environ, "ROS_DOMAIN_ID": domain},
        )
        try:
            source = DiagnosticsLiveSource()

            async def run() -> None:
                app = TopApp(source, interval=3600)  # refreshed by hand below
                async with app.run_test(size=(150, 40)) as pilot:
                    table = app.query_one("#slaves", DataTable)
                    deadline = time.monotonic() + 60
                    states: list[str] = []
                    while time.monotonic() < deadline:
                        app.refresh_view()
                        await pilot.pause(0.2)
                        states = (
                            [
                                table.get_row(k)[2]
                                for k in ("0", "1", "2", "3")
                                if table.is_valid_row_index(table.get_row_index(k))
                            ]
                            if table.row_count == 4
                            else []
                        )
                        stats = str(app.query_one("#stats", Static).content)
                        if states == ["OP"] * 4 and "cycle 400 µs" in stats:
                            break  # every slave in OP and the latched layout received
                        assert node.poll() is None, node.stderr.read() if node.stderr else ""
                    assert states == ["OP"] * 4
                    stats = str(app.query_one("#stats", Static).content)
                    assert "bus laelaps_ii   cycle 400 µs (2500 Hz)" in stats
                    assert "cycles 0 " not in stats
                    assert app.sub_title.startswith("node ether_comm")
                    assert "round trip" in str(app.query_one("#timing", Static).content)

            asyncio.run(run())
        finally:
            node.send_signal(signal.SIGINT)
            try:
                node.wait(timeout=20)
            except subprocess.TimeoutExpired:
                node.kill()
                node.wait()
