"""A real recording in seconds: the trot experiment on the in-process simulator.

Tests and demos need a recording with real data (simulated legs, the real master, the real
recorder) without a veth pair or root: :func:`record_simulated_trot` runs the simulator in this
process, behind the engine's in-process link, with the RT thread at normal priority.
"""

from __future__ import annotations

from pathlib import Path

from ether_ros.tools.experiments import TrotPlan, TrotResult, trot

DEFAULT_CONFIG = Path(__file__).resolve().parents[3] / "config" / "laelaps.yaml"


def record_simulated_trot(
    path: str | Path,
    config: str | Path = DEFAULT_CONFIG,
    transition_s: int = 1,
    hold_s: float = 2.0,
    settle_s: float = 0.5,
    realtime: bool = False,
) -> TrotResult:
    """Run the trot (Table 6.1, shortened) on simulated legs and record it to ``path``."""
    from ether_ros.config import load_bus_config
    from ether_ros.master.bus import Bus
    from ether_ros.sim.network import build_network

    cfg = load_bus_config(config)
    if not realtime:
        # Shared test machines: no CPU pinning, no SCHED_FIFO, no mlockall.
        cfg.bus.realtime.policy = "other"
        cfg.bus.realtime.cpu = None
        cfg.bus.realtime.lock_memory = False
    net = build_network(cfg)
    with Bus.open(cfg, link=net) as bus:
        bus.start()
        return trot(
            bus,
            TrotPlan(transition_s=transition_s, hold_s=hold_s, settle_s=settle_s),
            record=path,
            log=lambda _msg: None,
        )
