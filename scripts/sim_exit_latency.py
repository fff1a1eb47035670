#!/usr/bin/env python3
"""How long ``ether-ros sim`` takes to end after SIGTERM (frame loop stopped, control socket
removed, process gone), measured from the sender: ``scripts/sim_exit_latency.py [RUNS]``.
Needs root (a veth pair and a network namespace). Prints each run and the median in ms."""

from __future__ import annotations

import signal
import statistics
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "python"))

from ether_ros.testing.netns import VethPair, netns_command  # noqa: E402


def one(config: Path) -> float:
    with VethPair.create(netns=True) as veth:
        argv = [sys.executable, "-m", "ether_ros.cli.main", "sim", str(config),
                "--interface", veth.slave]  # fmt: skip
        proc = subprocess.Popen(
            netns_command(veth.netns, argv), stdout=subprocess.PIPE, stderr=subprocess.PIPE,
            text=True,
        )  # fmt: skip
        assert proc.stdout is not None
        if not proc.stdout.readline().strip().endswith("ready"):
            proc.kill()
            raise SystemExit(
                f"the simulator did not start: {proc.stderr.read() if proc.stderr else ''}"
            )
        start = time.monotonic()
        proc.send_signal(signal.SIGTERM)
        proc.wait()
        return (time.monotonic() - start) * 1000


def main() -> int:
    runs = int(sys.argv[1]) if len(sys.argv) > 1 else 10
    times = [one(REPO / "config" / "laelaps.yaml") for _ in range(runs)]
    print(" ".join(f"{t:.0f}" for t in times), "ms")
    print(f"median {statistics.median(times):.0f} ms, max {max(times):.0f} ms over {runs} runs")
    return 0


if __name__ == "__main__":
    sys.exit(main())
