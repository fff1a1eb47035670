"""`ether-ros top` on the running node: the simulator and `ether-ros run` in their own
processes over a real veth pair; the live view subscribes to the node's diagnostics. On a
terminal (a pty, top in its own process): the panic keys, SIGTERM, a node that dies."""

from __future__ import annotations

import asyncio
import math
import os
import random
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from ether_ros.ros.rig import RosRig
from ether_ros.sim.proof import SimProcess
from ether_ros.testing.netns import VethPair
from ether_ros.testing.pty import CTRL_P, F1, Pty
from ether_ros.testing.wait import wait_for

pytestmark = [pytest.mark.netns, pytest.mark.ros]

REPO = Path(__file__).resolve().parents[2]
LAELAPS = REPO / "config" / "laelaps.yaml"


def test_top_shows_the_running_nodes_slaves(
    veth_ns: VethPair, monkeypatch: pytest.MonkeyPatch
) -> None:
    import rclpy
    from textual.widgets import DataTable, Static

    from ether_ros.ros.top_source import DiagnosticsLiveSource
    from ether_ros.tools.live import TopApp

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


def top_on_a_terminal(rig: RosRig) -> Pty:
    term = Pty([sys.executable, "-m", "ether_ros.cli.main", "top"], env=rig.env)
    term.expect(r"OP", timeout=60)  # the node's diagnostics are on the screen
    return term


def hip_gain(rig: RosRig) -> float:
    return rig.client.latest.outputs.get("hind_right_leg", {}).get("Kp100_hip", math.nan)


def panicked(rig: RosRig) -> bool:
    return rig.client.master_status().get("panic") == "true"


def test_top_panics_on_ctrl_p_and_f1_ends_on_sigterm_and_marks_a_dead_node() -> None:
    """`ether-ros top` on a terminal (pty) against the node: Ctrl-P and F1 put the safe outputs
    on the wire (the node's panic state set); SIGTERM ends it cleanly; once the node is gone its
    screen says so and shows no slave in OP."""
    with RosRig(LAELAPS) as rig:
        c = rig.client
        assert c.wait_for_node() == "active"
        c.layout(timeout=10)
        with top_on_a_terminal(rig) as term:
            for key in (CTRL_P, F1):
                assert c.command("clear_panic")[0]
                assert c.write("hind_right_leg", "Kp100_hip", 2222)[0]
                wait_for("the commanded gain on the wire", lambda: hip_gain(rig) == 2222.0)
                wait_for("the panic to clear", lambda: not panicked(rig), 20)
                mark = term.mark()
                term.write(key)
                wait_for("the safe outputs on the wire", lambda: hip_gain(rig) == 0.0, 20)
                wait_for("the node's panic state", lambda: panicked(rig), 20)
                term.expect("PANIC: safe outputs on the wire", since=mark)
            assert "Command palette" not in term.text()
            c.command("clear_panic")
            assert rig.node_proc is not None
            rig.node_proc.kill()  # the node dies
            term.expect("STALE: no report from node ether_comm", timeout=30)
            term.expect(r"unknown: no report for", timeout=10)
            term.proc.send_signal(signal.SIGTERM)
            assert term.wait(timeout=30) == 0


def test_top_without_a_terminal_refuses_to_start() -> None:
    r = subprocess.run(
        [sys.executable, "-m", "ether_ros.cli.main", "top"],
        stdin=subprocess.DEVNULL,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert r.returncode == 2
    assert "needs a terminal" in r.stderr
