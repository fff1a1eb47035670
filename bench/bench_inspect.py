"""Inspection beside a running bus: what the tools cost the cycle when they ask the running
master (``ether_ros.claim``, ``master/service.py``) instead of opening the interface.

Setup: the simulated Laelaps II bus (`config/laelaps.yaml`, 4 legs) in its own network
namespace; our master (`Bus.open` + `start`) at 1 kHz in this process. Windows alternate (the
VM's load changes by the minute):
- *floor*: the bus alone;
- *inspect*: another process asks the running master in a loop, as `ether-ros slaves`,
  `states`, `upload` and `reg-read` do: `found`, `states`, an SDO upload of 0x1018:01 from every
  leg, a register read of 0x0130 from every leg.
Per window: cycles, frames lost or late, working-counter errors, and the requests answered.
The claim: the inspect windows lose no more cycles than the floor windows (ratio of lost
frames per 1000 cycles ≈ 1; both are the bus's own floor on this VM).
"""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path
from typing import Any

from ether_ros.config import load_bus_config
from ether_ros.master import Bus
from ether_ros.sim.proof import SimProcess
from ether_ros.testing.netns import VethPair
from report import Report

REPO = Path(__file__).resolve().parent.parent
CONFIG = REPO / "config" / "laelaps.yaml"
CYCLE_US = 1000
ROUNDS = 3

# The other process: the requests of the inspection commands, in a loop, counted.
CLIENT = """
import sys, time
from ether_ros.claim import OwnerClient
iface, seconds = sys.argv[1], float(sys.argv[2])
done = 0
with OwnerClient(iface) as c:
    legs = [s["position"] for s in c.request("found")]
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        c.request("found"); c.request("states")
        for p in legs:
            c.request("upload", position=p, index=0x1018, subindex=1)
            c.request("reg_read", position=p, address=0x130, length=2)
        done += 2 + 2 * len(legs)
print(done)
"""


def _counters(bus: Bus) -> dict[str, int]:
    s = bus.stats()
    return {k: int(s.get(k, 0)) for k in ("cycles", "lost", "late", "wkc_errors")}


def _window(bus: Bus, seconds: float, interface: str | None) -> dict[str, Any]:
    before = _counters(bus)
    requests = 0
    if interface is None:
        time.sleep(seconds)
    else:
        done = subprocess.run(
            [sys.executable, "-c", CLIENT, interface, str(seconds)],
            capture_output=True,
            text=True,
            timeout=seconds + 60,
            check=True,
        )
        requests = int(done.stdout.strip() or 0)
    after = _counters(bus)
    out: dict[str, Any] = {k: after[k] - before[k] for k in after}
    out["requests"] = requests
    return out


def run(report: Report) -> None:
    seconds = 3.0 if report.quick else 10.0
    cfg = load_bus_config(CONFIG)
    cfg.bus.cycle_us = CYCLE_US
    windows: dict[str, list[dict[str, Any]]] = {"floor": [], "inspect": []}
    with VethPair.create(netns=True) as veth, SimProcess(CONFIG, veth.slave, veth.netns):
        cfg.bus.interface = veth.master
        with Bus.open(cfg, interface=veth.master) as bus:
            bus.start()
            time.sleep(1.0)
            for _round in range(ROUNDS):
                windows["floor"].append(_window(bus, seconds, None))
                windows["inspect"].append(_window(bus, seconds, veth.master))
    rows = []
    totals = {}
    for kind, ws in windows.items():
        t = {k: sum(w[k] for w in ws) for k in ws[0]}
        totals[kind] = t
        per_k = 1000 * (t["lost"] + t["late"]) / max(t["cycles"], 1)
        rows.append(
            [
                kind,
                t["cycles"],
                t["lost"],
                t["late"],
                t["wkc_errors"],
                f"{per_k:.3f}",
                t["requests"],
                f"{t['requests'] / (ROUNDS * seconds):.0f}",
            ]
        )
    floor = totals["floor"]
    inspect = totals["inspect"]
    floor_rate = (floor["lost"] + floor["late"]) / max(floor["cycles"], 1)
    inspect_rate = (inspect["lost"] + inspect["late"]) / max(inspect["cycles"], 1)
    ratio = (
        "n/a (no loss in either)"
        if floor_rate == inspect_rate == 0
        else (f"{inspect_rate / floor_rate:.2f}" if floor_rate else "inf (the floor lost none)")
    )
    report.text(
        f"Laelaps II bus (4 legs) at {CYCLE_US} µs under our master; {ROUNDS} rounds of "
        f"{seconds:.0f} s windows, alternating: the bus alone (floor) and another process "
        "asking the running master in a loop (found, states, SDO upload 0x1018:01 and register "
        "0x0130 of every leg), as the inspection commands do beside a running node."
    )
    report.table(
        [
            "window",
            "cycles",
            "lost",
            "late",
            "wkc errors",
            "lost+late per 1000 cycles",
            "requests",
            "requests/s",
        ],
        rows,
    )
    report.text(f"Lost+late per cycle, inspect / floor: **{ratio}**.")
    report.value("windows", windows)
    report.value("ratio", ratio)
