"""Each slave's configuration state machine (``master/slave_fsm.py``) over the in-process link
to the real simulator: its steps in order, the step, timeout and AL status code in its errors,
bring-up of every slave in parallel, recovery of one slave while the others keep cycling, and a
configured slave that is missing."""

from __future__ import annotations

import time
from collections.abc import Iterator
from typing import Any

import pytest

from ether_ros._native import RefuseOp, Reset, StallMailbox
from ether_ros.errors import AlStateRefused, BusError
from ether_ros.master import Bus
from ether_ros.master.slave_fsm import STEPS, Hooks, SlaveFsm, SlaveStepError
from ether_ros.testing.wait import wait_for
from master_rigs import relaxed_config, sim_bus, sim_network


@pytest.fixture
def opened() -> Iterator[tuple[Bus, Any]]:
    with sim_bus() as opened:
        yield opened


def test_the_steps_run_in_order_and_each_has_a_timeout() -> None:
    names = [s.name for s in STEPS]
    assert names == ["address", "init", "mailbox", "preop", "coe", "process", "dc", "safeop",
                     "so", "outputs", "op"]  # fmt: skip
    assert all(s.timeout_s > 0 for s in STEPS)


def test_a_slave_taken_to_preop_by_its_machine_has_its_mailbox(opened: tuple[Bus, Any]) -> None:
    bus, _net = opened
    s = bus.slave("front_left_leg")
    seen: list[str] = []

    class Watch(SlaveFsm):
        def run(self, first: str, last: str) -> None:
            for step in STEPS[[x.name for x in STEPS].index(first) :]:
                super().run(step.name, step.name)
                seen.append(step.name)
                if step.name == last:
                    return

    Watch(s, bus.worker, Hooks(outputs=lambda _s: None)).run("address", "preop")
    assert seen == ["address", "init", "mailbox", "preop"]
    assert bus.states()[s.position].state == "PREOP"
    assert s.runtime.step == ""
    # Its mailbox works, through its one owner.
    assert s.sdo is not None and bus.worker.mailbox(s.station).sdo is s.sdo.client
    assert isinstance(bus.sdo_read("front_left_leg", 0x1018, 1), int)


def test_a_refused_op_names_the_step_and_the_al_status_code(opened: tuple[Bus, Any]) -> None:
    bus, net = opened
    net.inject(RefuseOp(slave=2))
    with pytest.raises(SlaveStepError) as err:
        bus.start()
    e = err.value
    assert e.step == "op" and e.code == 0x001A and e.timeout_s == 10.0
    assert isinstance(e.cause, AlStateRefused)
    assert e.slave == "slave 2 (front_left_leg)"
    assert "step op" in str(e) and "0x001A" in str(e)
    assert not bus.running


def test_a_stalled_mailbox_fails_its_step_after_its_timeout() -> None:
    """The drives' PDO assignment is read over CoE in the ``coe`` step: a drive whose mailbox
    stalls fails that step, naming it and its timeout."""
    cfg = relaxed_config("arm6.yaml")
    net = sim_network(cfg)
    with Bus.open(cfg, link=net, drift_frames=100) as bus:
        net.inject(StallMailbox(slave=1))
        with pytest.raises(SlaveStepError) as err:
            bus.start()
        e = err.value
        assert e.step == "coe" and e.timeout_s == 1.0
        assert "timed out after 1 s" in str(e) and str(e).count("elbow_drive") <= 2
        assert e.slave == "slave 1 (elbow_drive)" and e.state is not None


def test_a_power_cycled_slave_comes_back_while_the_others_keep_cycling(
    opened: tuple[Bus, Any],
) -> None:
    bus, net = opened
    bus.start()
    events: list[str] = []
    bus.on_event(lambda e: events.append(f"{e.kind} {e.slave}"))
    others = [s.name for s in bus.slaves if s.position != 3]
    fresh_while_away: list[bool] = []
    net.inject(Reset(slave=3))

    def back() -> bool:
        fresh_while_away.append(all(bus.inputs_fresh(n) for n in others))
        return "slave_recovered front_right_leg" in events

    wait_for("the power-cycled slave back in OP", back, timeout=20)
    assert "slave_lost front_right_leg" in events
    assert [s.state for s in bus.states()] == ["OP"] * 4
    s = bus.slave("front_right_leg")
    assert s.runtime.recoveries == 1 and not s.runtime.lost and s.runtime.step == ""
    # The others' frames kept coming back whole (their inputs fresh) most of the time it was
    # away; they were never taken out of OP.
    assert any(fresh_while_away)
    assert not any(f"slave_lost {n}" in events for n in others)


def test_a_configured_slave_missing_is_named() -> None:
    cfg = relaxed_config()
    net = sim_network(cfg)
    extra = cfg.slaves[-1].model_copy(update={"name": "fifth_leg", "position": None})
    cfg.slaves.append(extra)
    with pytest.raises(BusError, match=r"slave 4 \(fifth_leg\) is missing"):
        Bus.open(cfg, link=net)


def test_bring_up_and_recovery_are_the_same_machine(opened: tuple[Bus, Any]) -> None:
    bus, net = opened
    steps: list[tuple[str, str]] = []
    original = SlaveFsm.run

    def record(self: SlaveFsm, first: str, last: str) -> None:
        steps.append((first, last))
        original(self, first, last)

    SlaveFsm.run = record  # type: ignore[method-assign]
    try:
        bus.start()
        assert set(steps) == {("init", "process"), ("safeop", "so"), ("outputs", "op")}
        steps.clear()
        net.inject(Reset(slave=1))
        wait_for("recovered", lambda: bus.slave(1).runtime.recoveries == 1, timeout=20)
        assert ("address", "op") in steps
    finally:
        SlaveFsm.run = original  # type: ignore[method-assign]
    time.sleep(0)


def test_inspection_takes_a_slave_in_init_to_preop_and_leaves_a_working_one_alone(
    opened: tuple[Bus, Any],
) -> None:
    """The inspection mode of the machine (the tools' bring-up without a running master): a
    slave in INIT runs address..preop; a slave in OP keeps its state, and only its mailbox
    owner is set up (its SyncManagers are live)."""
    from ether_ros.master import slave_fsm

    bus, _net = opened
    s = bus.slave("front_left_leg")
    assert bus.states()[s.position].state == "INIT"
    slave_fsm.inspect(bus.worker, [s])
    assert bus.states()[s.position].state == "PREOP"
    assert isinstance(bus.sdo_read("front_left_leg", 0x1018, 1), int)
    bus.start()
    others = [o for o in bus.slaves if o is not s]
    slave_fsm.inspect(bus.worker, others)
    assert [st.state for st in bus.states()] == ["OP"] * 4
    assert all(o.runtime.last_error == "" for o in others)
    assert isinstance(bus.sdo_read(others[0].name, 0x1018, 1), int)
