"""The experiments' logic on the in-process simulator (the trot run itself is exercised in
test_tools_trot_recording.py)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from ether_ros.cli.main import main
from ether_ros.tools.experiments import (
    ExperimentError,
    Round,
    TrotPlan,
    frequency,
    frequency_table,
    leg_of,
    loop_times,
    trot,
)
from ether_ros.tools.recording import read_recording

REPO = Path(__file__).resolve().parents[2]


def load(name: str, cycle_us: int | None = None) -> Any:
    from ether_ros.config import load_bus_config

    cfg = load_bus_config(REPO / "config" / name)
    cfg.bus.realtime.policy = "other"  # shared test machine: no SCHED_FIFO, no pinning
    cfg.bus.realtime.cpu = None
    cfg.bus.realtime.lock_memory = False
    if cycle_us is not None:
        cfg.bus.cycle_us = cycle_us
    return cfg


def open_sim_bus(name: str, cycle_us: int | None = None) -> Any:
    from ether_ros.master.bus import Bus
    from ether_ros.sim.network import build_network

    cfg = load(name, cycle_us)
    return Bus.open(cfg, link=build_network(cfg))


def test_leg_names() -> None:
    assert [leg_of(n) for n in ("front_left_leg", "fore_right", "hind_left", "rear_right_leg")] == [
        "FL",
        "FR",
        "HL",
        "HR",
    ]
    with pytest.raises(ExperimentError, match="cannot tell which leg"):
        leg_of("leg_3")


def test_loop_times_and_their_errors() -> None:
    assert loop_times(400, 50, 100) == [400, 350, 300, 250, 200, 150, 100]
    assert loop_times(400, 50, 230) == [400, 350, 300, 250]
    with pytest.raises(ExperimentError, match="step-us must be positive"):
        loop_times(400, 0, 100)
    with pytest.raises(ExperimentError, match="must not be below"):
        loop_times(100, 50, 400)


def test_frequency_rounds_on_the_simulator(tmp_path: Path) -> None:
    logged: list[str] = []
    rounds = frequency(
        lambda us: open_sim_bus("laelaps.yaml", us),
        [400, 300],
        0.4,
        record=tmp_path / "freq.mcap",
        log=logged.append,
    )
    assert [r.cycle_us for r in rounds] == [400, 300]
    for r in rounds:
        assert not r.error and r.cycles > 100
        assert r.recording is not None
        rec = read_recording(r.recording)
        assert rec.bus.cycle_us == r.cycle_us
        assert rec.timing["cycle"].size == r.cycles
        assert rec.metadata["experiment"] == "frequency"
        # Standing still: a = b = 0 throughout (Table 6.1 without the ramps).
        assert rec.outputs["front_left_leg"]["a_ellipse100"].max() == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["freq_300us.mcap", "freq_400us.mcap"]
    table = frequency_table(rounds)
    assert table.splitlines()[2].split()[:2] == ["400", "2.500"]
    assert table.splitlines()[3].split()[:2] == ["300", "3.333"]


def test_frequency_table_reports_refused_op_and_the_best_round() -> None:
    rounds = [
        Round(400, 1.0, cycles=2500, lost=0),
        Round(350, 1.0, cycles=2857, lost=0),
        Round(300, 1.0, cycles=3333, lost=12),
        Round(220, 1.0, error="did not reach OP"),
    ]
    table = frequency_table(rounds)
    assert "220            4.545  did not reach OP" in table
    assert table.endswith("shortest loop time without lost frames: 350 µs (2.857 kHz)")


def test_trot_needs_laelaps_legs() -> None:
    bus = open_sim_bus("generic_io.yaml")
    try:
        with pytest.raises(ExperimentError, match="no slave has the Laelaps II trajectory"):
            trot(bus, TrotPlan(transition_s=0, hold_s=0))
        with pytest.raises(ExperimentError, match=r"transition time must be 0\.\.127"):
            trot(bus, TrotPlan(transition_s=200))
    finally:
        bus.close()


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (
            ["experiment", "frequency", "config/laelaps.yaml", "--step-us", "-5"],
            "--step-us must be positive",
        ),
        (["experiment", "trot", "no/such.yaml"], "no/such.yaml"),
        (
            ["experiment", "trot", "config/laelaps.yaml", "--watchdog-ms", "-1"],
            "--watchdog-ms must be 0..60000, got -1",
        ),
    ],
)
def test_cli_bad_input(
    argv: list[str],
    message: str,
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.chdir(REPO)
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1
