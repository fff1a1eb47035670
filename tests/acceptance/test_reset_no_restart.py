"""Resetting a stop does not restart the machine (ISO 13850; issue 24, item 3), checked on the
wire: what the simulated slaves receive, read from the simulator's own probes and the drives'
states, with the simulator in its own process and network namespace across a veth pair.

- Laelaps II (config/laelaps.yaml) through the ROS node and the operator console: legs told to
  trot (State_Machine 1, a 5, b 4), panic, clear: every leg keeps receiving its safe outputs
  until commanded again, the console and the node's snapshots say so, and a new command to one
  leg changes that leg only (and only what it writes).
- The 6-axis arm (config/arm6.yaml) through ``Bus``: axes moving and a drive's digital outputs
  set, panic, clear: no axis is enabled or moves and the digital outputs stay off until a new
  command; an explicit enable of one axis enables that axis only, without moving it.

Nothing is timed: every check waits for a condition, or holds over a span of the simulated
firmware's own time.
"""

from __future__ import annotations

import subprocess
import sys
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

from ether_ros.config import BusConfig, load_bus_config
from ether_ros.master import Bus
from ether_ros.ros.rig import RosRig
from ether_ros.sim.proof import SimProcess
from ether_ros.testing.configs import config_with_watchdog
from ether_ros.testing.netns import VethPair
from ether_ros.testing.wait import wait_for

pytestmark = [pytest.mark.netns]

REPO = Path(__file__).resolve().parents[2]
ARM6 = REPO / "config" / "arm6.yaml"
# Slave positions of the legs in config/laelaps.yaml.
LEGS = {"hind_right_leg": 0, "hind_left_leg": 1, "front_left_leg": 2, "front_right_leg": 3}
STANDING = (
    "x_cntr_traj1000=0 y_cntr_traj1000=599 a_ellipse100=0 b_ellipse100=0 traj_freq100=100 "
    "phase_deg=0 FlatnessParam100=0"
)
# What a leg's firmware receives from the safe image (State_Machine 0, everything else 0).
SAFE_LEG = {"cmd_state_machine": 0.0, "cmd_a_m": 0.0, "cmd_b_m": 0.0, "cmd_y_c_m": 0.0,
            "cmd_kp_knee": 0.0, "cmd_transition_time_s": 0.0}  # fmt: skip
# The leg firmware's mode when it follows its trajectory (the probe's "mode").
MODE_OPERATIONAL = 2.0
# Simulated firmware time over which "nothing changes" is checked.
HOLD_S = 1.0


def _hold(
    what: str, probe: Callable[[], dict[str, Any]], check: Callable[[dict[str, Any]], None]
) -> None:
    """``check`` (which asserts) holds in every probe until the simulated firmware has run
    ``HOLD_S`` more seconds: a span of the simulation's own time, not of the test's."""
    start = float(probe()["firmware_time_s"])

    def held() -> bool:
        p = probe()
        check(p)
        return float(p["firmware_time_s"]) >= start + HOLD_S

    wait_for(what, held, timeout=60)


# ------------------------------------------------------------------------------ Laelaps II
@pytest.fixture(scope="module")
def rig(veth_allowed: bool, tmp_path_factory: pytest.TempPathFactory) -> Iterator[RosRig]:
    if not veth_allowed:
        pytest.fail("the ROS acceptance tests need root (veth pairs)")
    # config/laelaps.yaml without its 100 ms command watchdog: on a loaded 2-core VM the node's
    # feeder can stall that long, and a trip (which also voids the commands before it) would
    # be taken for what this test looks for. The watchdog's own reset is covered by the
    # engine's tests and tests/acceptance/test_ros_node.py.
    config = config_with_watchdog("laelaps.yaml", tmp_path_factory.mktemp("laelaps"), 0)
    with RosRig(config) as rig:
        assert rig.client.wait_for_node() == "active"
        rig.client.layout(timeout=10)
        yield rig


def console(rig: RosRig, *args: str) -> subprocess.CompletedProcess[str]:
    """The console in its own process (it takes the control lease at its first command)."""
    rig.client.release_lease()
    r = subprocess.run(
        [sys.executable, "-m", "ether_ros.cli.main", "console", *args],
        input="",
        env=rig.env,
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert r.returncode == 0, r.stdout + r.stderr
    return r


def legs_probe(rig: RosRig) -> dict[str, Any]:
    """Every leg's probe, and the firmware time of the first."""
    probes = {leg: rig.sim("probe", slave=pos) for leg, pos in LEGS.items()}
    return {"firmware_time_s": probes["hind_right_leg"]["firmware_time_s"], "legs": probes}


def received(p: dict[str, Any], keys: dict[str, float]) -> dict[str, float]:
    return {k: round(float(p[k]), 6) for k in keys}


@pytest.mark.ros
@pytest.mark.slow
def test_laelaps_clear_after_a_panic_does_not_resume_the_trot(rig: RosRig) -> None:
    console(
        rig,
        "-c", "set all State_Machine=0 Transition_time=3",
        "-c", f"set all {STANDING}",
        "-c", "set all State_Machine=1",
        "-c", "set all a_ellipse100=5 b_ellipse100=4",
    )  # fmt: skip
    trotting = {"cmd_state_machine": 1.0, "cmd_a_m": 0.05, "cmd_b_m": 0.04}
    for leg, pos in LEGS.items():
        wait_for(
            f"{leg} told to trot",
            lambda pos=pos: received(rig.sim("probe", slave=pos), trotting) == trotting,
        )
    r = console(rig, "-c", "panic")
    assert "PANIC: safe outputs on the wire" in r.stdout, r.stdout
    for leg, pos in LEGS.items():
        wait_for(
            f"{leg} on its safe outputs",
            lambda pos=pos: received(rig.sim("probe", slave=pos), SAFE_LEG) == SAFE_LEG,
        )
    r = console(rig, "-c", "clear")
    assert "outputs stay at their safe values until you command them again" in r.stdout, r.stdout

    def all_safe(p: dict[str, Any]) -> None:
        for leg, probe in p["legs"].items():
            assert received(probe, SAFE_LEG) == SAFE_LEG, f"{leg} after the clear: {probe}"
            assert probe["mode"] != MODE_OPERATIONAL, f"{leg} runs its trajectory: {probe}"

    _hold("the legs to stay on their safe outputs", lambda: legs_probe(rig), all_safe)
    # The node's caches say the same: the commanded outputs (pdo_out_timer) and the wire echo
    # (pdo_out) show the safe values, not the trot.
    for leg in LEGS:
        rig.client.wait_for(
            lambda latest, leg=leg: (
                latest.commanded.get(leg, {}).get("State_Machine") == 0.0
                and latest.commanded[leg].get("a_ellipse100") == 0.0
                and latest.outputs.get(leg, {}).get("b_ellipse100") == 0.0
            ),
            timeout=10,
        )
    r = console(rig, "-c", "get front_left_leg a_ellipse100")
    assert "front_left_leg.a_ellipse100 = 0" in r.stdout, r.stdout

    # A new command to one leg: that leg takes what was written, nothing else comes back.
    console(rig, "-c", "set front_left_leg Kp100_knee=1234 Transition_time=2")
    wait_for(
        "front_left_leg commanded again",
        lambda: (
            rig.sim("probe", slave=LEGS["front_left_leg"])["cmd_kp_knee"] == pytest.approx(12.34)
        ),
    )

    def only_front_left(p: dict[str, Any]) -> None:
        for leg, probe in p["legs"].items():
            expected = dict(SAFE_LEG)
            if leg == "front_left_leg":
                expected.update(cmd_kp_knee=12.34, cmd_transition_time_s=2.0)
            assert received(probe, SAFE_LEG) == expected, f"{leg}: {probe}"

    _hold("the other legs to stay safe", lambda: legs_probe(rig), only_front_left)


# ------------------------------------------------------------------------------ 6-axis arm
def _arm_config(interface: str) -> BusConfig:
    cfg = load_bus_config(ARM6, interface=interface)
    # A shared 2-core VM: no CPU pinning, no mlockall of the test process, no watchdog (the
    # watchdog's own reset is covered by the engine's tests and test_ros_node).
    cfg.bus.realtime.cpu = None
    cfg.bus.realtime.lock_memory = False
    cfg.bus.watchdog_ms = 0
    return cfg


@pytest.fixture
def arm(veth_ns: VethPair) -> Iterator[tuple[Bus, SimProcess]]:
    with (
        SimProcess(ARM6, veth_ns.slave, veth_ns.netns) as sim,
        Bus.open(_arm_config(veth_ns.master), drift_frames=500) as bus,
    ):
        bus.start()
        yield bus, sim


# The elbow drive's digital outputs 16-31 come back as its digital inputs 16-31 (0x60FD).
DIGITAL_OUT = float(0x0005_0000)


def test_arm6_clear_after_a_panic_enables_and_moves_nothing(
    arm: tuple[Bus, SimProcess],
) -> None:
    bus, sim = arm
    axes = bus.axes()
    for a in axes:
        a.enable(timeout=5)
    elbow = bus.axis("elbow")
    elbow.set_extras({"outputs": DIGITAL_OUT})
    wait_for("the digital outputs echoed", lambda: int(elbow.extras["inputs"]) >> 16 == 5)
    # Every joint on its way somewhere when the panic comes.
    for a in axes:
        p0 = a.position
        a.follow([(0.0, p0, 0.0), (3.0, p0 + 0.4, 0.0)], start_in=0.05)
    wait_for("under way", lambda: all(a.status()["trajectory_active"] for a in axes))
    bus.panic()
    wait_for("every axis stopped", lambda: all(a.state != "operation_enabled" for a in axes))
    wait_for("standstill", lambda: all(abs(a.velocity) < 1e-3 for a in axes))
    wait_for("digital outputs off", lambda: int(elbow.extras["inputs"]) >> 16 == 0)
    stopped = {a.name: a.position for a in axes}
    bus.clear_panic()
    assert not bus.engine.is_panicked
    # The commanded outputs are the safe ones: what was set before the panic is gone.
    assert elbow.extras["outputs"] == 0.0

    def probe() -> dict[str, Any]:
        drives = [sim.request({"op": "probe", "slave": k}) for k in range(3)]
        return {"firmware_time_s": bus.engine.now_ns() / 1e9, "drives": drives}

    def nothing_restarts(_p: dict[str, Any]) -> None:
        for a in axes:
            assert a.state != "operation_enabled", f"{a.name} re-enabled by the clear"
            assert abs(a.position - stopped[a.name]) < 2e-3, f"{a.name} moved after the clear"
        assert int(elbow.extras["inputs"]) >> 16 == 0, "the digital outputs came back"

    _hold("nothing to restart", probe, nothing_restarts)
    assert all(a.status()["restart_blocked"] for a in axes)

    # An explicit enable of one axis: that axis only, and it stays where it is.
    elbow.enable(timeout=5)
    _hold("the other axes to stay stopped", probe, lambda _p: _only_elbow(axes, stopped))
    assert int(elbow.extras["inputs"]) >> 16 == 0, "an enable is no command for the outputs"
    elbow.set_extras({"outputs": DIGITAL_OUT})
    wait_for("the digital outputs commanded again", lambda: int(elbow.extras["inputs"]) >> 16 == 5)


def _only_elbow(axes: list[Any], stopped: dict[str, float]) -> None:
    for a in axes:
        want = "operation_enabled" if a.name == "elbow" else None
        if want:
            assert a.state == want, a.state
        else:
            assert a.state != "operation_enabled", f"{a.name} enabled with the elbow"
        assert abs(a.position - stopped[a.name]) < 2e-3, f"{a.name} moved"
