"""Figures of a recording: the thesis's trot figures 6.5–6.11 and the loop timing.

Every figure is built from a :class:`~ether_ros.tools.recording.Recording` as a matplotlib
``Figure`` (Agg, no display), so tests can inspect the lines and the CLI can save PNG and SVG.

The leg conventions, the limits and the steady-state window are those of
:mod:`ether_ros.tools.trot_metrics`, which puts the same figures into numbers.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from matplotlib.axes import Axes
from matplotlib.figure import Figure

from ether_ros.tools.recording import Recording, RecordingError
from ether_ros.tools.trot_metrics import (
    LegLimits,
    forward_kinematics,
    leg_slaves,
    steady_state_mask,
)

DESIRED_COLOR = "red"
ACTUAL_COLOR = "black"
LIMIT_COLOR = "red"

__all__ = [
    "LegLimits",
    "build_figures",
    "forward_kinematics",
    "leg_slaves",
    "save_figures",
    "steady_state_mask",
    "timing_figure",
    "toe_figure",
]


def _time_axis(rec: Recording, cycles: np.ndarray) -> np.ndarray:
    return rec.wake_times_s(cycles)


def _grid(n: int) -> tuple[int, int]:
    cols = 2 if n > 1 else 1
    return math.ceil(n / cols), cols


def _new_figure(title: str, n: int) -> tuple[Figure, list[Axes]]:
    rows, cols = _grid(n)
    height = 3.2 * rows + 0.5
    fig = Figure(figsize=(5.0 * cols, height))
    # Fixed margins instead of a layout engine: the engines redraw the figure several times,
    # which costs seconds per figure on a busy machine.
    fig.subplots_adjust(
        left=0.08,
        right=0.98,
        bottom=0.5 / height + 0.03,
        top=1 - 0.6 / height,
        hspace=0.5,
        wspace=0.22,
    )
    axes = [fig.add_subplot(rows, cols, i + 1) for i in range(n)]
    fig.suptitle(title)
    return fig, axes


def toe_figure(rec: Recording, legs: Sequence[str]) -> Figure:
    """Figure 6.5: desired (red) and actual (black) toe path of each leg, steady state."""
    fig, axes = _new_figure("Toe trajectory: desired (red) and actual (black)", len(legs))
    for ax, leg in zip(axes, legs, strict=True):
        s = rec.inputs[leg]
        mask = steady_state_mask(rec, leg)
        for kind, prefix, color in (
            ("desired", "desired_", DESIRED_COLOR),
            ("actual", "", ACTUAL_COLOR),
        ):
            t1 = np.radians(s[f"{prefix}hip_angle"][mask] / 100.0)
            t2 = np.radians(s[f"{prefix}knee_angle"][mask] / 100.0)
            x, y = forward_kinematics(t1, t2)
            ax.plot(x, y, color=color, linewidth=1.0, label=kind)
        ax.set_title(leg)
        ax.set_xlabel("x [mm]")
        ax.set_ylabel("y [mm]")
        ax.set_aspect("equal", adjustable="datalim")
        if not ax.yaxis_inverted():
            ax.invert_yaxis()  # y points down from the hip
        ax.legend(loc="upper right", fontsize="small")
    return fig


def _time_figure(
    rec: Recording,
    legs: Sequence[str],
    title: str,
    ylabel: str,
    pairs: Sequence[tuple[str, str, float, str]],
    limit: float | None = None,
) -> Figure:
    """Per-leg time plots: ``pairs`` are (variable, label, scale, color)."""
    fig, axes = _new_figure(title, len(legs))
    for ax, leg in zip(axes, legs, strict=True):
        s = rec.inputs[leg]
        t = _time_axis(rec, s.cycle)
        for var, label, scale, color in pairs:
            ax.plot(t, s[var] * scale, color=color, linewidth=0.8, label=label)
        if limit is not None:
            for sign in (1, -1):
                ax.axhline(
                    sign * limit,
                    color=LIMIT_COLOR,
                    linestyle="--",
                    linewidth=1.0,
                    label="limit" if sign > 0 else "_nolegend_",
                )
        ax.set_title(leg)
        ax.set_xlabel("time [s]")
        ax.set_ylabel(ylabel)
        ax.legend(loc="upper right", fontsize="small")
    return fig


def timing_figure(rec: Recording) -> Figure:
    """Histograms of the loop timing of every recorded cycle (µs, log counts)."""
    fig, axes = _new_figure(
        f"Loop timing, {rec.timing.get('cycle', np.empty(0)).size} cycles of {rec.bus.cycle_us} µs",
        4,
    )
    panels = (
        ("wake_latency_ns", "wake-up latency [µs]"),
        ("exec_ns", "execution [µs]"),
        ("period_ns", "period [µs]"),
        ("rtt_ns", "round trip [µs]"),
    )
    for ax, (key, label) in zip(axes, panels, strict=True):
        data = rec.timing.get(key, np.empty(0)).astype(float) / 1000.0
        if key == "rtt_ns":
            data = data[data > 0]  # 0: no reply processed in that cycle
        if key == "period_ns" and data.size:
            data = data[1:]  # the first cycle has no predecessor
        if data.size:
            ax.hist(data, bins=60, color=ACTUAL_COLOR, log=True)
            ax.set_title(f"median {np.median(data):.1f}, max {data.max():.1f} µs", fontsize="small")
        else:
            ax.set_title("no data", fontsize="small")
        ax.set_xlabel(label)
        ax.set_ylabel("cycles")
    return fig


def build_figures(rec: Recording, limits: LegLimits | None = None) -> dict[str, Figure]:
    """All figures the recording supports, by file stem."""
    limits = limits or LegLimits()
    figures: dict[str, Figure] = {}
    legs = leg_slaves(rec)
    if legs:
        figures["fig6_5_toe_trajectory"] = toe_figure(rec, legs)
        figures["fig6_6_knee_angle"] = _time_figure(
            rec,
            legs,
            "Knee angle: desired (red) and actual (black)",
            "knee angle [deg]",
            [
                ("desired_knee_angle", "desired", 0.01, DESIRED_COLOR),
                ("knee_angle", "actual", 0.01, ACTUAL_COLOR),
            ],
        )
        figures["fig6_7_hip_angle"] = _time_figure(
            rec,
            legs,
            "Hip angle: desired (red) and actual (black)",
            "hip angle [deg]",
            [
                ("desired_hip_angle", "desired", 0.01, DESIRED_COLOR),
                ("hip_angle", "actual", 0.01, ACTUAL_COLOR),
            ],
        )
        figures["fig6_8_knee_pwm"] = _time_figure(
            rec,
            legs,
            f"Knee PWM command and limit (±{limits.pwm_knee_pct} %)",
            "PWM [%]",
            [("PWM10000_knee", "PWM", 0.01, ACTUAL_COLOR)],
            limits.pwm_knee_pct,
        )
        figures["fig6_9_hip_pwm"] = _time_figure(
            rec,
            legs,
            f"Hip PWM command and limit (±{limits.pwm_hip_pct} %)",
            "PWM [%]",
            [("PWM10000_hip", "PWM", 0.01, ACTUAL_COLOR)],
            limits.pwm_hip_pct,
        )
        figures["fig6_10_knee_velocity"] = _time_figure(
            rec,
            legs,
            f"Knee velocity and limit (±{limits.speed_knee_rad_s:.2f} rad/s)",
            "velocity [rad/s]",
            [("velocity_knee1000", "velocity", 0.001, ACTUAL_COLOR)],
            limits.speed_knee_rad_s,
        )
        figures["fig6_11_hip_velocity"] = _time_figure(
            rec,
            legs,
            f"Hip velocity and limit (±{limits.speed_hip_rad_s:.2f} rad/s)",
            "velocity [rad/s]",
            [("velocity_hip1000", "velocity", 0.001, ACTUAL_COLOR)],
            limits.speed_hip_rad_s,
        )
    if rec.timing:
        figures["loop_timing"] = timing_figure(rec)
    if not figures:
        raise RecordingError(
            f"recording {rec.path} has neither leg variables nor loop timing to plot"
        )
    return figures


def save_figures(
    figures: dict[str, Figure], outdir: str | Path, formats: Sequence[str] = ("png", "svg")
) -> list[Path]:
    out = Path(outdir)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise RecordingError(f"cannot create output directory {out}: {exc.strerror}") from exc
    written: list[Path] = []
    for stem, fig in figures.items():
        for fmt in formats:
            path = out / f"{stem}.{fmt}"
            fig.savefig(path, dpi=110)
            written.append(path)
    return written
