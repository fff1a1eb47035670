"""The trot experiment on the in-process simulator, recorded, read back and plotted.

One real run (simulated legs, the real master and engine, the real recorder) feeds every test
in this module; nothing here is synthetic.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from matplotlib.lines import Line2D

from ether_ros.tools.experiments import TrotResult
from ether_ros.tools.plots import build_figures, forward_kinematics, save_figures
from ether_ros.tools.recording import Recording, read_recording
from ether_ros.tools.sim_recording import record_simulated_trot

LEGS = ["hind_right_leg", "hind_left_leg", "front_left_leg", "front_right_leg"]


@pytest.fixture(scope="module")
def trot_run(tmp_path_factory: pytest.TempPathFactory) -> tuple[TrotResult, Recording]:
    path = tmp_path_factory.mktemp("trot") / "trot.mcap"
    result = record_simulated_trot(path, transition_s=1, hold_s=3.0, settle_s=0.3)
    return result, read_recording(path)


def test_trot_follows_table_6_1(trot_run: tuple[TrotResult, Recording]) -> None:
    result, rec = trot_run
    assert result.legs == {
        "hind_right_leg": "HR",
        "hind_left_leg": "HL",
        "front_left_leg": "FL",
        "front_right_leg": "FR",
    }
    assert [p.name for p in result.phases] == [
        "stand",
        "b -> 4 cm",
        "a -> 5 cm",
        "trot",
        "a -> 0",
        "b -> 0",
        "stand",
    ]
    fl = rec.outputs["front_left_leg"]
    # The commands as recorded: phases of Table 6.1, a and b up to 5 and 4 cm and back to 0.
    assert fl["phase_deg"].max() == 180 and rec.outputs["front_right_leg"]["phase_deg"].max() == 0
    # (max, not the last sample: on a loaded machine the command watchdog may have put the
    # safe outputs, all zero, on the wire for a moment.)
    assert fl["y_cntr_traj1000"].max() == 599
    assert rec.outputs["hind_left_leg"]["y_cntr_traj1000"].max() == 598
    assert fl["a_ellipse100"].max() == 5 and fl["b_ellipse100"].max() == 4
    assert fl["a_ellipse100"][-1] == 0 and fl["b_ellipse100"][-1] == 0
    # b rises before a and falls after it.
    first_b = fl.cycle[np.argmax(fl["b_ellipse100"] > 0)]
    first_a = fl.cycle[np.argmax(fl["a_ellipse100"] > 0)]
    assert first_b < first_a


def test_recording_holds_every_cycle_layout_joints_and_statistics(
    trot_run: tuple[TrotResult, Recording],
) -> None:
    result, rec = trot_run
    assert [s.name for s in rec.bus.slaves] == LEGS
    assert rec.bus.cycle_us == 400
    cycles = rec.timing["cycle"]
    assert cycles.size == result.cycles_recorded > 1000
    assert np.all(np.diff(cycles.astype(np.int64)) > 0)
    # Decoded values every ros.decoded_decimation (10) cycles.
    steps = np.diff(rec.inputs["hind_right_leg"].cycle.astype(np.int64))
    assert set(np.unique(steps)) <= {10, 20, 30}
    assert "hip_angle" in rec.inputs["hind_right_leg"].columns
    assert list(rec.joints["name"]) == [
        "hr_hip",
        "hr_knee",
        "hl_hip",
        "hl_knee",
        "fl_hip",
        "fl_knee",
        "fr_hip",
        "fr_knee",
    ]
    # joint position = hip_angle (deg*100) * 0.000174533 rad
    hip = rec.inputs["hind_right_leg"]["hip_angle"][-1] * 0.000174533
    assert rec.joints["position"][-1][0] == pytest.approx(hip, abs=1e-9)
    assert rec.statistics and "lost_frames" in rec.statistics[-1]
    assert rec.metadata["experiment"] == "trot"


def test_legs_actually_moved(trot_run: tuple[TrotResult, Recording]) -> None:
    _result, rec = trot_run
    for leg in LEGS:
        knee = rec.inputs[leg]["knee_angle"] / 100.0
        assert knee.max() - knee.min() > 5.0, leg  # degrees: the leg stepped


def test_the_result_carries_the_steady_trot_report(
    trot_run: tuple[TrotResult, Recording],
) -> None:
    result, _rec = trot_run
    assert [r.slave for r in result.report] == LEGS
    for r in result.report:
        assert r.samples > 100, r
        # No knee chatters between its limits (the defect of issue 21): at most a small share.
        assert r.knee.share_at_limit < 0.05, r
        assert r.toe_error_rms_mm < 15.0, r


def test_forward_kinematics_eq_4_1() -> None:
    x, y = forward_kinematics(np.array([0.0, math.pi / 2]), np.array([0.0, math.pi / 2]))
    assert x[0] == pytest.approx(0.0) and y[0] == pytest.approx(600.0)
    assert x[1] == pytest.approx(600.0) and y[1] == pytest.approx(0.0, abs=1e-9)


def _data_lines(ax: object) -> list[Line2D]:
    return [
        ln
        for ln in ax.get_lines()
        if ln.get_label() != "_nolegend_"  # type: ignore[attr-defined]
        and ln.get_label() != "limit"
    ]


def _limit_values(ax: object) -> set[float]:
    return {
        round(float(ln.get_ydata()[0]), 2)
        for ln in ax.get_lines()  # type: ignore[attr-defined]
        if ln.get_linestyle() == "--"
    }


def test_figures_6_5_to_6_11_and_timing(
    trot_run: tuple[TrotResult, Recording], tmp_path: Path
) -> None:
    _result, rec = trot_run
    figs = build_figures(rec)
    assert list(figs) == [
        "fig6_5_toe_trajectory",
        "fig6_6_knee_angle",
        "fig6_7_hip_angle",
        "fig6_8_knee_pwm",
        "fig6_9_hip_pwm",
        "fig6_10_knee_velocity",
        "fig6_11_hip_velocity",
        "loop_timing",
    ]
    for name in list(figs)[:7]:
        axes = figs[name].axes
        assert [ax.get_title() for ax in axes] == LEGS, name
    toe = figs["fig6_5_toe_trajectory"].axes[0]
    assert (toe.get_xlabel(), toe.get_ylabel()) == ("x [mm]", "y [mm]")
    assert [ln.get_color() for ln in toe.get_lines()] == ["red", "black"]
    desired_y = toe.get_lines()[0].get_ydata()
    # Steady trot: the desired toe stays on the 599/598 mm stance line and lifts by b = 40 mm.
    assert float(np.max(desired_y)) == pytest.approx(598, abs=3)
    assert float(np.min(desired_y)) == pytest.approx(558, abs=3)
    for name in ("fig6_6_knee_angle", "fig6_7_hip_angle"):
        ax = figs[name].axes[0]
        assert [ln.get_label() for ln in ax.get_lines()] == ["desired", "actual"]
        assert ax.get_xlabel() == "time [s]" and "[deg]" in ax.get_ylabel()
    for name, limit in (
        ("fig6_8_knee_pwm", 38.25),
        ("fig6_9_hip_pwm", 41.17),
        ("fig6_10_knee_velocity", 6.41),
        ("fig6_11_hip_velocity", 7.94),
    ):
        for ax in figs[name].axes:
            assert len(_data_lines(ax)) == 1, name
            assert _limit_values(ax) == {limit, -limit}, name
    timing = figs["loop_timing"].axes
    assert [ax.get_xlabel() for ax in timing] == [
        "wake-up latency [µs]",
        "execution [µs]",
        "period [µs]",
        "round trip [µs]",
    ]
    assert all(len(ax.patches) > 0 for ax in timing)

    written = save_figures({"fig6_8_knee_pwm": figs["fig6_8_knee_pwm"]}, tmp_path)
    assert [p.name for p in written] == ["fig6_8_knee_pwm.png", "fig6_8_knee_pwm.svg"]
    assert written[0].read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    svg = written[1].read_text()
    assert "PWM [%]" in svg and "38.25" in svg
