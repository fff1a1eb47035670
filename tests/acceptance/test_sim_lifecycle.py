"""The simulator process: SIGTERM stops the frame loop, then removes the control socket and
ends; a second simulator on the same interface is refused (two would answer every frame
twice), and once the first has ended a new one starts at once. How fast it ends is measured by
``scripts/sim_exit_latency.py`` (docs/simulator.md), not asserted here."""

from __future__ import annotations

import signal
import subprocess
import sys
from pathlib import Path

import pytest

from ether_ros.sim.control import request
from ether_ros.sim.proof import SimProcess
from ether_ros.testing.netns import VethPair, netns_command
from ether_ros.testing.wait import wait_for

pytestmark = pytest.mark.netns

CONFIG = Path(__file__).resolve().parents[2] / "config" / "generic_io.yaml"


def test_sigterm_stops_the_loop_then_the_socket_and_a_second_simulator_is_refused() -> None:
    with VethPair.create(netns=True) as veth:
        first = SimProcess(CONFIG, veth.slave, veth.netns).start()
        try:
            assert request(first.control, {"op": "stats"}) is not None
            # Same interface, another control socket path: still refused, by the lock.
            argv = [sys.executable, "-m", "ether_ros.cli.main", "sim", str(CONFIG),
                    "--interface", veth.slave, "--no-control"]  # fmt: skip
            second = subprocess.run(
                netns_command(veth.netns, argv), capture_output=True, text=True, timeout=60
            )
            assert second.returncode == 2, second.stderr
            lines = second.stderr.strip().splitlines()
            assert len(lines) == 1 and "another simulator is already running on" in lines[0]
            assert "Traceback" not in second.stderr
            # The first one did not notice.
            assert request(first.control, {"op": "stats"}) is not None
            proc = first.proc
            assert proc is not None
            proc.send_signal(signal.SIGTERM)
            wait_for("the simulator to end", lambda: proc.poll() is not None, timeout=30)
            assert proc.returncode == 0
            assert not first.control.exists()
        finally:
            first.stop()
        # The lock went with the process: a new simulator starts on the interface at once.
        with SimProcess(CONFIG, veth.slave, veth.netns) as again:
            assert again.ready_line.endswith("ready")
