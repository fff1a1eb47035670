"""The Axis API over a real bus: config/arm6.yaml brought to OP through the in-process link to
the simulator (no root needed). Without the drive model the simulator runs its generic
loopback firmware for ServoDrive2 (each output copied to the input of the same type: the
statusword echoes the controlword), which never leaves Not Ready to Switch On: enough for the
refusals, the stuck-enable error and the stop; the drive's behaviour is tested against the
CiA 402 drive model in tests/acceptance/test_cia402_veth.py."""

from __future__ import annotations

import math
from collections.abc import Iterator
from pathlib import Path

import pytest

from ether_ros._native import DriveFault
from ether_ros.config import load_bus_config
from ether_ros.config.bus import BusConfig
from ether_ros.config.process import ProcessValueError
from ether_ros.master import Bus
from ether_ros.master.axis import AxisCommandError, AxisError
from ether_ros.testing.wait import wait_for
from master_rigs import relaxed_config

REPO = Path(__file__).resolve().parents[2]


def _config(path: Path = REPO / "config" / "arm6.yaml") -> BusConfig:
    cfg = relaxed_config(path)
    for s in cfg.slaves:
        s.sim.device = "loopback"
        # Without real-time scheduling a loaded machine can starve the loop past the slaves'
        # own process-data watchdog (a communication fault): these tests are about the modes,
        # the restart rule has tests of its own (test_cia402_modes_veth.py).
        for a in s.axes:
            a.restart = "auto"
    return cfg


@pytest.fixture
def bus() -> Iterator[Bus]:
    from ether_ros.sim.network import build_network

    cfg = _config()
    with Bus.open(cfg, link=build_network(cfg), drift_frames=100) as b:
        yield b


def test_axes_are_listed_and_refuse_commands_before_op(bus: Bus) -> None:
    names = [a.name for a in bus.axes()]
    assert names == ["shoulder_pan", "shoulder_lift", "elbow", "wrist_1", "wrist_2", "wrist_3"]
    assert [a.index for a in bus.axes()] == list(range(6))
    with pytest.raises(AxisCommandError, match="no axis 'knee' on this bus"):
        bus.axis("knee")
    elbow = bus.axis("elbow")
    with pytest.raises(AxisCommandError, match="the bus is not in OP"):
        elbow.enable()
    with pytest.raises(AxisCommandError, match="the bus is not in OP"):
        elbow.command(position=0.1)


def test_bad_commands_are_refused_and_write_nothing(bus: Bus) -> None:
    bus.start()
    elbow = bus.axis("elbow")
    before = elbow.status()["command_seq"]
    cases = [
        (dict(position=math.nan), "position nan is not a finite number"),
        (dict(position=2.6), r"position 2.6 is outside the limits \[-2.5, 2.5\]"),
        (dict(velocity=0.1), "a velocity command for an axis in mode csp"),
        (dict(position=0.1, velocity=0.1), "give exactly one of position, velocity, torque"),
        ({}, "got none"),
    ]
    for kwargs, message in cases:
        with pytest.raises(AxisCommandError, match=message):
            elbow.command(**kwargs)
    with pytest.raises(AxisCommandError, match="unknown mode 'vl'"):
        elbow.set_mode("vl")
    with pytest.raises(AxisCommandError, match=r"trajectory point 2: t 0\.5 is not after 0\.5"):
        elbow.follow([(0.0, 0.0, 0.0), (0.5, 0.1, 0.0), (0.5, 0.2, 0.0)])
    with pytest.raises(AxisCommandError, match=r"trajectory point 0: velocity 9 is beyond"):
        elbow.follow([(0.0, 0.0, 9.0)])
    assert elbow.status()["command_seq"] == before
    # The axis owns its drive's controlword: a variable write there is refused.
    with pytest.raises(ProcessValueError, match="belongs to axis elbow"):
        bus.write("elbow_drive", "0x6040:00", 0x0F)


def test_a_drive_that_never_enables_is_named_with_its_state(bus: Bus) -> None:
    bus.start()
    wrist = bus.axis("wrist_3")
    with pytest.raises(AxisError, match=r"axis wrist_3: no operation_enabled within 0.3 s: "
                       r"stuck in not_ready_to_switch_on \(statusword 0x0000, error code "
                       r"0x0000"):  # fmt: skip
        wrist.enable(timeout=0.3)
    st = wrist.status()
    assert st["enable_wanted"] and st["state"] == "not_ready_to_switch_on"
    # While not enabled, the target is the actual position (the loopback returns the target as
    # the actual: it stays where the drive reported it).
    assert st["target_position_raw"] == st["position_raw"]


def test_panic_reaches_every_drive_as_its_stop_command(bus: Bus) -> None:
    bus.start()
    axes = bus.axes()
    # The loopback pairs outputs with inputs in PDO order: only each drive's first axis gets
    # its controlword back as its statusword.
    echoing = [a for a in axes if a.spec.axis_index == 0]
    for a in axes:
        bus.engine.axis_enable(a.index, True)
    # Wanted enabled, in Not Ready the controlword is 0.
    wait_for("controlword 0", lambda: all(a.status()["statusword"] == 0 for a in echoing))
    bus.panic()
    # Quick stop (0x0002) went to every drive: it came back from the drives.
    wait_for("quick stop", lambda: all(a.status()["statusword"] == 0x0002 for a in echoing))
    assert all(a.status()["halted"] and a.status()["controlword"] == 0x0002 for a in axes)
    bus.clear_panic()
    # restart: auto here (see _config): back to the enable sequence by itself.
    wait_for("enabled again", lambda: all(a.status()["statusword"] == 0 for a in echoing))
    bus.stop()
    assert [s.state for s in bus.states()] == ["INIT"] * 3


@pytest.fixture
def drives() -> Iterator[Bus]:
    """arm6 on the simulator's CiA 402 drive model (its default for ServoDrive2)."""
    from ether_ros.sim.network import build_network

    cfg = _config()
    for s in cfg.slaves:
        s.sim.device = None
    assert {s.sim_device for s in cfg.slaves} == {"cia402"}
    with Bus.open(cfg, link=build_network(cfg), drift_frames=100) as b:
        b.start()
        yield b


def test_every_mode_runs_on_the_drive_model(drives: Bus) -> None:
    j = drives.axis("elbow")
    # Cyclic modes switch while enabled; 0x6061 confirms each.
    j.enable(timeout=3)
    j.set_mode("csv")
    j.command(velocity=0.2)
    wait_for("csv velocity", lambda: abs(j.velocity - 0.2) < 0.01)
    j.set_mode("cst")
    assert j.status()["mode_display"] == "cst"
    j.command(torque=0.0)
    # Profile modes too switch while enabled (from the actual state).
    j.set_mode("pp")
    # Profile position: the new set-point handshake (controlword bit 4, statusword bit 12).
    start = j.position
    j.command(position=start + 0.05)
    wait_for("pp target reached", lambda: abs(j.position - (start + 0.05)) < 0.002)
    # Profile velocity.
    j.set_mode("pv")
    j.command(velocity=-0.1)
    wait_for("pv velocity", lambda: abs(j.velocity + 0.1) < 0.01)
    # Homing only at standstill: the axis still moves at -0.1 rad/s.
    with pytest.raises(AxisCommandError, match="switch from pv to hm only at standstill"):
        j.set_mode("hm")
    j.command(velocity=0.0)
    wait_for("pv standstill", lambda: j.status()["idle"])
    # Homing (method 37: the current position is the home) starts only when asked, ends on the
    # drive's "homing attained" and gives the axis back in pv, holding.
    runs = j.status()["homing_runs"]
    j.home(method=37, timeout=10)
    st = j.status()
    assert st["homing_runs"] == runs + 1
    assert st["mode_display"] == "pv" and st["state"] == "operation_enabled"
    # The home offset (0x607C, 0) is the position now.
    assert abs(j.position - j.spec.config.position_offset) < 0.01
    j.set_mode("hm")
    with pytest.raises(AxisCommandError, match="takes no setpoint"):
        j.command(position=0.0)


def test_homing_refuses_a_method_the_drive_lacks_or_a_disabled_axis(drives: Bus) -> None:
    j = drives.axis("elbow")
    j.enable(timeout=3)
    # 0x60E3 of the ESI: 19, 33, 34, 35, 37.
    assert j.spec.homing_methods is not None and 37 in j.spec.homing_methods
    with pytest.raises(AxisCommandError, match="does not offer homing method 1 "):
        j.home(method=1)
    assert j.status()["homing_runs"] == 0 and j.mode == "csp"
    # Homing needs the axis enabled.
    j.disable()
    with pytest.raises(AxisCommandError, match="needs the axis enabled"):
        j.home(method=37)


def test_homing_on_the_index_pulse_ends_attained_and_holds(drives: Bus) -> None:
    j = drives.axis("wrist_1")
    j.enable(timeout=3)
    j.home(method=34, timeout=20)
    st = j.status()
    assert st["homing_runs"] == 1 and st["mode_display"] == "csp"
    # Held where homing left it: the target follows the actual position.
    assert abs(st["target_position"] - st["position"]) < 0.01


def test_profile_velocity_and_acceleration_per_command_in_si(drives: Bus) -> None:
    j = drives.axis("elbow")
    j.enable(timeout=3)
    with pytest.raises(AxisCommandError, match="for modes pp and pv"):
        j.command(position=0.1, profile_velocity=0.5)
    j.set_mode("pp")
    with pytest.raises(AxisCommandError, match="must be a positive number"):
        j.command(position=0.1, profile_velocity=-1.0)
    with pytest.raises(AxisCommandError, match="must be a positive number"):
        j.command(position=0.1, profile_acceleration=math.nan)
    start = j.position
    j.command(position=start + 0.05, profile_velocity=0.5, profile_acceleration=5.0)
    scale = j.spec.config.velocity_scale
    assert drives.sdo_read("elbow_drive", 0x6081, 0) == round(0.5 / scale)
    assert drives.sdo_read("elbow_drive", 0x6083, 0) == round(5.0 / scale)
    wait_for("pp target reached", lambda: abs(j.position - (start + 0.05)) < 0.002)


def _extras_config() -> BusConfig:
    """The shipped arm6 on the drive model: its elbow has extras (inputs, outputs, velocity
    offset)."""
    cfg = _config(REPO / "config" / "arm6.yaml")
    for s in cfg.slaves:
        s.sim.device = None
    return cfg


def test_extras_read_and_command_in_si_on_the_drive_model() -> None:
    from ether_ros.sim.network import build_network

    cfg = _extras_config()
    with Bus.open(cfg, link=build_network(cfg), drift_frames=100) as b:
        b.start()
        j = b.axis("elbow")
        assert set(j.extras) == {"inputs", "outputs", "velocity_offset"}
        assert j.spec.extras["outputs"].writable and not j.spec.extras["inputs"].writable
        # Refused, nothing written: an input, an unknown extra, NaN, too big for its object.
        with pytest.raises(AxisCommandError, match="is an input"):
            j.set_extras({"inputs": 1.0})
        with pytest.raises(AxisCommandError, match="no extra 'nope'"):
            j.set_extras({"outputs": 1.0, "nope": 1.0})
        with pytest.raises(AxisCommandError, match="not a finite number"):
            j.set_extras({"outputs": math.nan})
        with pytest.raises(AxisCommandError, match="extra 'outputs'"):
            j.set_extras({"outputs": 2.0**33})
        assert j.extras["outputs"] == 0.0
        # The model wires outputs 16-31 back to inputs 16-31.
        j.set_extras({"outputs": float(0x0005_0000)})
        wait_for("outputs read back", lambda: int(j.extras["inputs"]) & 0xFFFF_0000 == 0x0005_0000)
        # The velocity offset is feed-forward: added to the csv velocity command.
        j.set_mode("csv")
        j.enable(timeout=3)
        j.command(velocity=0.0)
        j.set_extras({"velocity_offset": 0.1})
        wait_for("velocity offset", lambda: abs(j.velocity - 0.1) < 0.01)
        j.set_extras({"velocity_offset": 0.0})
        wait_for("offset removed", lambda: abs(j.velocity) < 0.01)


def test_an_object_mapped_by_the_master_reaches_the_drive(tmp_path: Path) -> None:
    """Axis 2's target velocity is missing from the ESI's RxPDO 0x1610: the loader appends it,
    the master writes the mapping in PREOP, and the drive model (which maps what the master
    configured) runs the csv axis on it."""
    from ether_ros.sim.network import build_network

    entry = ("<Entry><Index>#x68FF</Index><SubIndex>0</SubIndex><BitLen>32</BitLen>"
             "<Name>Target velocity</Name><DataType>DINT</DataType></Entry>")  # fmt: skip
    esi = tmp_path / "servo.xml"
    text = (REPO / "devices" / "servo_drive.xml").read_text()
    esi.write_text(text.replace(entry, "<Entry><Index>#x0</Index><BitLen>32</BitLen></Entry>"))
    yaml = tmp_path / "bus.yaml"
    yaml.write_text(
        f"bus: {{name: one, interface: eth0, cycle_us: 2000, watchdog_ms: 0,\n"
        f"      realtime: {{policy: other, lock_memory: false}}}}\n"
        f"esi: [{esi}]\n"
        "slaves:\n"
        "  - name: drive\n"
        "    device: ServoDrive2\n"
        "    axes:\n"
        "      - {name: j1, position_scale: 7.66990394e-6}\n"
        "      - {name: j2, mode: csv, velocity_scale: 7.66990394e-6}\n"
    )
    cfg = load_bus_config(yaml)
    with Bus.open(cfg, link=build_network(cfg), drift_frames=100) as bus:
        bus.start()
        j2 = bus.axis("j2")
        j2.enable(timeout=3)
        j2.command(velocity=0.25)
        wait_for("csv velocity through the new mapping", lambda: abs(j2.velocity - 0.25) < 0.01)
        # Six entries as in the ESI (one now padding), then 0x68FF:00, 32 bits.
        assert bus.sdo_read("drive", 0x1610, 0) == 7
        assert bus.sdo_read("drive", 0x1610, 7) == 0x68FF0020


def test_stop_takes_every_axis_out_of_operation_enabled_first(drives: Bus) -> None:
    for a in drives.axes():
        a.enable(timeout=3)
    drives.stop()
    # The last status the RT thread published before the cyclic exchange stopped.
    states = [drives.engine.axis_status(i)["state"] for i in range(6)]
    assert "operation_enabled" not in states, states
    assert all(drives.engine.axis_status(i)["controlword"] == 0x0002 for i in range(6))


def test_a_trajectory_for_an_axis_out_of_operation_enabled_is_refused() -> None:
    """Issue 19: a trajectory sent to a faulted axis was answered "accepted", then dropped.
    Refused with the drive's state (and its error) and what to do; nothing is handed over."""
    from ether_ros.sim.network import build_network

    cfg = _config()
    for s in cfg.slaves:
        s.sim.device = None
        for a in s.axes:
            a.fault_reset = "manual"
    net = build_network(cfg)
    with Bus.open(cfg, link=net, drift_frames=100) as b:
        b.start()
        wrist = b.axis("wrist_1")
        handed = dict(b.axis_trajectories)
        track = [(0.5, 0.1, 0.0)]
        with pytest.raises(AxisCommandError, match=r"axis wrist_1 is \w+, not operation_enabled: "
                           "a trajectory is refused; enable the axis first"):  # fmt: skip
            wrist.follow(track)
        wrist.enable()
        net.inject(DriveFault(slave=1, error="encoder", axis=2))  # elbow_drive axis 2: wrist_1
        wait_for("the fault", lambda: wrist.status()["state"] == "fault")
        with pytest.raises(
            AxisCommandError,
            match=r"axis wrist_1 is in fault \(error 0x7305: incremental encoder 1 fault\): "
            "a trajectory is refused; reset_fault, then enable the axis",
        ):
            wrist.follow(track)
        assert b.axis_trajectories == handed, "nothing was handed to the engine"
        wrist.reset_fault()
        wrist.enable()
        wrist.follow(track)
        seq = b.axis_trajectories[wrist.index]
        wait_for("the trajectory taken", lambda: wrist.status()["command_seq"] >= seq)


@pytest.mark.parametrize("event", ["set_mode", "disable", "fault", "panic"])
def test_a_trajectory_that_stops_early_raises_its_reason(event: str) -> None:
    """Issue 24: a trajectory for two axes, one of which leaves it (switched to csv, disabled,
    faulted, or the bus panics). ``wait_trajectories`` raises ``TrajectoryStopped`` naming the
    joint and what happened, for either axis (the one that did not leave it names the other's
    reason), instead of waiting for an end that never comes; the other axis makes a quiet stop
    far short of the trajectory's end (10 s: waiting for less proves the early end)."""
    from ether_ros.master.axis import TrajectoryStopped
    from ether_ros.sim.network import build_network

    cfg = _config()
    for s in cfg.slaves:
        s.sim.device = None
        for a in s.axes:
            a.fault_reset = "manual"
    net = build_network(cfg)
    with Bus.open(cfg, link=net, drift_frames=100) as b:
        b.start()
        elbow, wrist = b.axis("elbow"), b.axis("wrist_1")
        for a in (elbow, wrist):
            a.enable(timeout=5)
        e0, w0 = elbow.position, wrist.position
        b.follow({"elbow": [(10.0, e0 + 1.0, 0.0)], "wrist_1": [(10.0, w0 + 1.0, 0.0)]})
        # Taken over by the engine on both axes (no speed is asked of a loaded machine).
        wait_for(
            "the trajectory running",
            lambda: all(a.status()["trajectory_active"] for a in (elbow, wrist)),
            timeout=30,
        )
        if event == "set_mode":
            wrist.set_mode("csv")
            reason = r"joint 'wrist_1' left csp \(now csv\)"
        elif event == "disable":
            wrist.disable()
            reason = "joint 'wrist_1' disabled"
        elif event == "fault":
            net.inject(DriveFault(slave=1, error="encoder", axis=2))  # elbow_drive axis 2
            reason = r"joint 'wrist_1' fault 0x7305 \(incremental encoder 1 fault\)"
        else:
            b.panic()
            reason = r"panic \(joint '(elbow|wrist_1)' stopped\)"
        for names in (["elbow"], ["wrist_1"], ["elbow", "wrist_1"]):
            with pytest.raises(TrajectoryStopped, match=reason):
                b.wait_trajectories(names, timeout=8.0)
        if event == "panic":
            b.clear_panic()
        wait_for("elbow at rest", lambda: abs(elbow.velocity) < 1e-3 and elbow.status()["idle"])
        st = elbow.status()
        assert st["trajectory_stopped"] and not st["trajectory_done"], st
        assert abs(elbow.position - e0) < 0.8, (e0, elbow.position)
