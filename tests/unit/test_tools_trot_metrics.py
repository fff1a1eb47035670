"""The steady-trot report: the share of time at the PWM limit per leg and joint, peaks and the
toe's distance from the desired path, on synthetic series and a synthetic recording whose
answers are known by construction."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from ether_ros.tools.recording import (
    BusInfo,
    RecordingWriter,
    SlaveInfo,
    VariableInfo,
    read_recording,
)
from ether_ros.tools.trot_metrics import (
    LEG_VARIABLES,
    LegLimits,
    at_limit,
    format_trot_report,
    forward_kinematics,
    longest_stretch,
    path_distances_mm,
    share_at_limit,
    stretches,
    trot_report,
)


def test_a_sample_is_at_the_limit_when_it_rounds_to_it() -> None:
    # PWM10000 is % x 100: the firmware clamps at exactly 38.25 % and reports 3825.
    pwm = np.array([0, 3825, -3825, 3824, 100, 4000, -3826])
    assert list(at_limit(pwm, 38.25)) == [False, True, True, False, False, True, True]
    assert share_at_limit(pwm, 38.25) == pytest.approx(4 / 7)
    assert share_at_limit(np.array([4116, -4116]), 41.17) == 0.0  # 41.16 % is not the limit
    assert share_at_limit(np.array([4117]), 41.17) == 1.0
    assert share_at_limit(np.array([]), 38.25) == 0.0


def test_stretches_at_the_limit_and_the_longest_one() -> None:
    flags = np.array([1, 1, 0, 0, 1, 1, 1, 1, 0, 1], dtype=bool)
    t = np.arange(flags.size) * 0.004
    assert stretches(flags) == 3
    assert longest_stretch(flags, t) == pytest.approx(3 * 0.004)  # samples 4..7
    assert stretches(np.zeros(5, dtype=bool)) == 0
    assert longest_stretch(np.zeros(5, dtype=bool), t[:5]) == 0.0


def test_distance_from_the_path() -> None:
    s = np.linspace(0, 2 * math.pi, 2000)
    path_x, path_y = 50 * np.cos(s), 580 + 40 * np.sin(s)
    # Points 5 mm outside a circle of radius 40 around the same centre... (here: the ellipse's
    # top and bottom, straight above and below, where the nearest path point is straight in y)
    x = np.array([0.0, 0.0, 50.0])
    y = np.array([580 - 45.0, 580 + 43.0, 580.0])
    d = path_distances_mm(x, y, path_x, path_y)
    assert d == pytest.approx([5.0, 3.0, 0.0], abs=0.05)
    assert np.isnan(path_distances_mm(x, y, np.empty(0), np.empty(0))).all()


# ---- a synthetic recording ------------------------------------------------------------------

CYCLE_US = 400
DECIMATION = 10


def _var(name: str) -> VariableInfo:
    return VariableInfo(name, "INT", 0x6000, 1, 16, -32768, 32767)


def _leg_bus() -> BusInfo:
    return BusInfo(
        "laelaps",
        CYCLE_US,
        (
            SlaveInfo(
                "front_left_leg",
                0,
                "LaelapsII_Leg",
                tuple(_var(n) for n in LEG_VARIABLES),
                (_var("a_ellipse100"), _var("Transition_time")),
            ),
        ),
    )


def _angles(cycle: int) -> tuple[float, float]:
    """Thigh and shank angles (deg) of a toe going round a small loop."""
    phase = 2 * math.pi * cycle * CYCLE_US * 1e-6  # 1 Hz
    return 4.0 + 10.0 * math.sin(phase), -3.0 + 8.0 * math.cos(phase)


def _write(path: Path, toe_offset_deg: float) -> None:
    """10000 cycles (4 s), outputs sampled every 10 cycles, inputs 5 cycles later. a_ellipse100
    = 5 from cycle 2000 to 9000, Transition_time 1 s (2500 cycles): the steady trot is cycles
    4500..9000, 450 input samples (4505..8995). In it the knee PWM sits at the limit for cycles
    5000..5490 (49 samples) and 7000..7090 (9 samples); it is also at the limit outside the
    window, which must not count. The hip stays at 41.16 %, just below its limit. The measured
    hip angle is ``toe_offset_deg`` off the desired one."""
    with RecordingWriter(path, _leg_bus()) as writer:
        for out_cycle in range(0, 10_000, DECIMATION):
            a = 5.0 if 2000 <= out_cycle <= 9000 else 0.0
            writer.write_values(out_cycle, {}, {"front_left_leg": [a, 1.0]})
            cycle = out_cycle + 5
            hip, knee = _angles(cycle)
            knee_pwm = 1000.0
            if 5000 <= cycle <= 5490 or cycle < 1000:
                knee_pwm = 3825.0
            if 7000 <= cycle <= 7090:
                knee_pwm = -3825.0
            inputs = {
                "hip_angle": (hip + toe_offset_deg) * 100,
                "desired_hip_angle": hip * 100,
                "knee_angle": knee * 100,
                "desired_knee_angle": knee * 100,
                "PWM10000_knee": knee_pwm,
                "PWM10000_hip": -4116.0,
                "velocity_knee1000": 7000.0 if cycle == 6005 else 500.0,
                "velocity_hip1000": -1500.0,
            }
            writer.write_values(cycle, {"front_left_leg": [inputs[n] for n in LEG_VARIABLES]}, {})


def test_report_of_a_recorded_trot(tmp_path: Path) -> None:
    path = tmp_path / "trot.mcap"
    _write(path, toe_offset_deg=0.0)
    rec = read_recording(path)
    assert not rec.timing  # decoded values only: no invented loop timing
    (r,) = trot_report(rec)
    assert r.slave == "front_left_leg"
    assert r.samples == 450
    assert r.seconds == pytest.approx((8995 - 4505) * CYCLE_US * 1e-6)
    assert r.knee.share_at_limit == pytest.approx(58 / 450)
    assert r.knee.stretches_at_limit == 2
    assert r.knee.longest_at_limit_s == pytest.approx(480 * CYCLE_US * 1e-6)
    assert r.knee.peak_pwm_pct == pytest.approx(38.25)
    assert r.hip.share_at_limit == 0.0 and r.hip.stretches_at_limit == 0
    assert r.hip.peak_pwm_pct == pytest.approx(41.16)
    assert r.knee.peak_speed_rad_s == pytest.approx(7.0)
    assert r.knee.peak_speed_rad_s > r.knee.speed_limit_rad_s == pytest.approx(6.41, abs=0.01)
    assert r.hip.peak_speed_rad_s == pytest.approx(1.5)
    assert r.toe_error_rms_mm == pytest.approx(0.0, abs=1e-9)
    text = format_trot_report([r])
    assert "front_left_leg" in text and "12.9%" in text and "0.0%" in text
    assert "±38.25 %" in text and "±41.17 %" in text


def test_toe_error_of_a_leg_off_its_path(tmp_path: Path) -> None:
    path = tmp_path / "trot.mcap"
    _write(path, toe_offset_deg=2.0)
    (r,) = trot_report(read_recording(path))
    # The measured toe runs the desired loop shifted by 2° of thigh angle: ~l1 * 2° = 8.7 mm
    # away at most, less where the shifted loop crosses the desired one.
    hip, knee = np.radians(np.array([_angles(c) for c in range(0, 2500, 10)]).T)
    x, y = forward_kinematics(hip + math.radians(2.0), knee)
    dx, dy = forward_kinematics(hip, knee)
    expected = path_distances_mm(x, y, dx, dy)
    assert 0.0 < r.toe_error_rms_mm <= r.toe_error_max_mm <= 250 * math.radians(2.0) + 0.1
    assert r.toe_error_max_mm == pytest.approx(float(expected.max()), rel=0.05)


def test_limits_are_those_of_table_6_1_and_the_gearheads() -> None:
    limits = LegLimits()
    assert (limits.pwm_knee_pct, limits.pwm_hip_pct) == (38.25, 41.17)
    # GP 52 C: 6000 rpm at the input, through 637/12 (knee) or 343/8 (hip) and the 48/26 pulley.
    assert limits.speed_knee_rad_s == pytest.approx(6000 * 2 * math.pi / 60 / (637 / 12 * 48 / 26))
    assert limits.speed_hip_rad_s == pytest.approx(6000 * 2 * math.pi / 60 / (343 / 8 * 48 / 26))
