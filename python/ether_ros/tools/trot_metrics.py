"""What chapter 6 of the thesis reads off its trot figures, as numbers.

The thesis judges its trot by eye (§6.2.2.1): the toe paths against the desired ellipse
(Fig. 6.5), the PWM commands against their limits (Figs. 6.8/6.9: "the commands in both hind
legs are always within the limit", "hip PWM limits are recurrently reached, especially in the
hind legs") and the velocities against the motor speed limits (Figs. 6.10/6.11). This module
turns a recording of the trot into those judgements, leg by leg and joint by joint, over the
steady trot:

- the share of time each joint's PWM command sits at its limit, and the longest such stretch;
- the peak PWM and the peak velocity estimate against their limits;
- how far the toe runs from the desired path: the distance of every measured toe point to the
  nearest point of the desired path (both from eq. 4.1), RMS and maximum.

Conventions (Laelaps II leg, thesis eq. 4.1 and Table 4.2): ``hip_angle`` is the thigh angle θ1
and ``knee_angle`` the shank angle θ2, both absolute from the downward vertical, in deg × 100;
``PWM10000_*`` is % × 100; ``velocity_*1000`` is rad/s × 1000. The toe is at
x = l1 sin θ1 + l2 sin θ2, y = l1 cos θ1 + l2 cos θ2 with y pointing down from the hip.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ether_ros.tools.recording import Recording

L1_MM = 250.0
L2_MM = 350.0

LEG_VARIABLES = (
    "hip_angle",
    "desired_hip_angle",
    "knee_angle",
    "desired_knee_angle",
    "PWM10000_knee",
    "PWM10000_hip",
    "velocity_knee1000",
    "velocity_hip1000",
)


@dataclass(frozen=True)
class LegLimits:
    """Limits the thesis draws on its figures. PWM: Table 6.1 (the motors' continuous current).

    Speed: the GP 52 C gearhead's maximum input speed, 6000 rpm, through its ratio and the
    48/26 pulley (hip 343/8, knee 637/12), as joint speed in rad/s.
    """

    pwm_knee_pct: float = 38.25
    pwm_hip_pct: float = 41.17
    speed_knee_rad_s: float = 6000 / (637 / 12 * 48 / 26) * 2 * math.pi / 60
    speed_hip_rad_s: float = 6000 / (343 / 8 * 48 / 26) * 2 * math.pi / 60


def forward_kinematics(theta1: np.ndarray, theta2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Eq. 4.1: toe (x, y) in mm from the thigh and shank angles in rad."""
    x = L1_MM * np.sin(theta1) + L2_MM * np.sin(theta2)
    y = L1_MM * np.cos(theta1) + L2_MM * np.cos(theta2)
    return x, y


def leg_slaves(rec: Recording) -> list[str]:
    """Slaves whose inputs carry the Laelaps II leg variables, in bus order."""
    return [
        s.name
        for s in sorted(rec.bus.slaves, key=lambda s: s.position)
        if s.name in rec.inputs and all(v in rec.inputs[s.name].columns for v in LEG_VARIABLES)
    ]


def steady_state_mask(rec: Recording, slave: str) -> np.ndarray:
    """Samples of the steady trot: the step length (``a_ellipse100``) commanded at its largest,
    from one ``Transition_time`` after that command (the firmware ramps over that time) until
    the command goes down again. Without those outputs in the recording, every sample counts.
    """
    inputs = rec.inputs[slave]
    everything = np.ones(inputs.cycle.size, dtype=bool)
    outputs = rec.outputs.get(slave)
    if outputs is None or "a_ellipse100" not in outputs.columns or outputs.cycle.size == 0:
        return everything
    a = outputs["a_ellipse100"]
    top = a.max()
    if top <= 0:
        return everything
    # In time, not in cycles: cycles skipped under load would shift a cycle-count window.
    at_top = rec.wake_times_s(outputs.cycle[a >= top])
    lo, hi = float(at_top.min()), float(at_top.max())
    if "Transition_time" in outputs.columns:
        ramp_s = float(outputs["Transition_time"][a >= top].max())
        if lo + ramp_s < hi:
            lo += ramp_s
    t = rec.wake_times_s(inputs.cycle)
    return (t >= lo) & (t <= hi)


def at_limit(pwm10000: np.ndarray, limit_pct: float) -> np.ndarray:
    """Which samples of a ``PWM10000_*`` series (% × 100) sit at the limit (%).

    The firmware clamps its output to exactly ±limit and reports round(PWM × 100), so a sample
    is at the limit when it rounds to it."""
    return np.abs(np.asarray(pwm10000, dtype=float)) >= limit_pct * 100.0 - 0.5


def share_at_limit(pwm10000: np.ndarray, limit_pct: float) -> float:
    """The share (0..1) of samples at the PWM limit; 0 for an empty series."""
    flags = at_limit(pwm10000, limit_pct)
    return float(np.mean(flags)) if flags.size else 0.0


def longest_stretch(flags: np.ndarray, times_s: np.ndarray) -> float:
    """The longest run of consecutive true samples, in seconds (first to last sample of the
    run; a single sample counts as 0 s)."""
    flags = np.asarray(flags, dtype=bool)
    if not flags.any():
        return 0.0
    padded = np.concatenate(([False], flags, [False])).astype(np.int8)
    starts = np.flatnonzero(np.diff(padded) == 1)
    ends = np.flatnonzero(np.diff(padded) == -1) - 1
    return float(np.max(times_s[ends] - times_s[starts]))


def stretches(flags: np.ndarray) -> int:
    """How many separate runs of true samples there are."""
    flags = np.asarray(flags, dtype=bool)
    return int(np.count_nonzero(flags[1:] & ~flags[:-1]) + (1 if flags.size and flags[0] else 0))


def path_distances_mm(
    x: np.ndarray, y: np.ndarray, path_x: np.ndarray, path_y: np.ndarray, chunk: int = 512
) -> np.ndarray:
    """For every point (x, y), the distance to the nearest point of the path (all in mm)."""
    px, py = np.asarray(path_x, dtype=float), np.asarray(path_y, dtype=float)
    if px.size == 0:
        return np.full(np.asarray(x).shape, np.nan)
    out = np.empty(np.asarray(x).size)
    xs, ys = np.asarray(x, dtype=float).ravel(), np.asarray(y, dtype=float).ravel()
    for i in range(0, xs.size, chunk):
        dx = xs[i : i + chunk, None] - px[None, :]
        dy = ys[i : i + chunk, None] - py[None, :]
        out[i : i + chunk] = np.sqrt(np.min(dx * dx + dy * dy, axis=1))
    return out


@dataclass(frozen=True)
class JointReport:
    """One joint over the steady trot."""

    limit_pct: float
    share_at_limit: float  # 0..1
    stretches_at_limit: int
    longest_at_limit_s: float
    peak_pwm_pct: float
    speed_limit_rad_s: float
    peak_speed_rad_s: float


@dataclass(frozen=True)
class LegReport:
    """One leg over the steady trot."""

    slave: str
    seconds: float
    samples: int
    knee: JointReport
    hip: JointReport
    toe_error_rms_mm: float
    toe_error_max_mm: float
    toe_x_range_mm: tuple[float, float]


def _joint(
    pwm10000: np.ndarray, velocity1000: np.ndarray, t: np.ndarray, limit: float, speed: float
) -> JointReport:
    flags = at_limit(pwm10000, limit)
    return JointReport(
        limit_pct=limit,
        share_at_limit=share_at_limit(pwm10000, limit),
        stretches_at_limit=stretches(flags),
        longest_at_limit_s=longest_stretch(flags, t),
        peak_pwm_pct=float(np.max(np.abs(pwm10000))) / 100.0 if pwm10000.size else 0.0,
        speed_limit_rad_s=speed,
        peak_speed_rad_s=float(np.max(np.abs(velocity1000))) / 1000.0 if velocity1000.size else 0.0,
    )


def leg_report(rec: Recording, slave: str, limits: LegLimits | None = None) -> LegReport:
    """The steady-trot report of one leg slave of the recording."""
    limits = limits or LegLimits()
    s = rec.inputs[slave]
    mask = steady_state_mask(rec, slave)
    t = rec.wake_times_s(s.cycle[mask])

    def col(name: str) -> np.ndarray:
        return np.asarray(s[name][mask], dtype=float)

    x, y = forward_kinematics(
        np.radians(col("hip_angle") / 100), np.radians(col("knee_angle") / 100)
    )
    dx, dy = forward_kinematics(
        np.radians(col("desired_hip_angle") / 100), np.radians(col("desired_knee_angle") / 100)
    )
    err = path_distances_mm(x, y, dx, dy)
    return LegReport(
        slave=slave,
        seconds=float(t[-1] - t[0]) if t.size > 1 else 0.0,
        samples=int(mask.sum()),
        knee=_joint(
            col("PWM10000_knee"),
            col("velocity_knee1000"),
            t,
            limits.pwm_knee_pct,
            limits.speed_knee_rad_s,
        ),
        hip=_joint(
            col("PWM10000_hip"),
            col("velocity_hip1000"),
            t,
            limits.pwm_hip_pct,
            limits.speed_hip_rad_s,
        ),
        toe_error_rms_mm=float(np.sqrt(np.mean(err**2))) if err.size else math.nan,
        toe_error_max_mm=float(np.max(err)) if err.size else math.nan,
        toe_x_range_mm=(float(x.min()), float(x.max())) if x.size else (math.nan, math.nan),
    )


def trot_report(rec: Recording, limits: LegLimits | None = None) -> list[LegReport]:
    """The steady-trot report of every Laelaps II leg in the recording, in bus order."""
    return [leg_report(rec, slave, limits) for slave in leg_slaves(rec)]


def format_trot_report(reports: list[LegReport]) -> str:
    """The report as a table (what ``ether-ros experiment trot`` and ``ether-ros plot`` print)."""
    if not reports:
        return "no Laelaps II leg variables in the recording: nothing to report"
    first = reports[0]
    lines = [
        f"Steady trot ({first.seconds:.1f} s, {first.samples} samples per leg): "
        "share of time at the PWM limit (Figs. 6.8, 6.9),",
        "peak PWM and speed against their limits (Figs. 6.10, 6.11), toe distance from the "
        "desired path (Fig. 6.5)",
        f"{'leg':18} {'at PWM limit':>19} {'longest':>15} {'peak PWM':>15} {'peak speed':>13}"
        f" {'toe error':>16}",
        f"{'':18} {'knee':>9} {'hip':>9} {'knee':>7} {'hip':>7} {'knee':>7} {'hip':>7}"
        f" {'knee':>6} {'hip':>6} {'RMS':>7} {'max':>8}",
    ]
    for r in reports:
        lines.append(
            f"{r.slave:18} {100 * r.knee.share_at_limit:8.1f}% {100 * r.hip.share_at_limit:8.1f}%"
            f" {1000 * r.knee.longest_at_limit_s:5.0f}ms {1000 * r.hip.longest_at_limit_s:5.0f}ms"
            f" {r.knee.peak_pwm_pct:6.1f}% {r.hip.peak_pwm_pct:6.1f}%"
            f" {r.knee.peak_speed_rad_s:6.2f} {r.hip.peak_speed_rad_s:6.2f}"
            f" {r.toe_error_rms_mm:5.1f}mm {r.toe_error_max_mm:6.1f}mm"
        )
    lines.append(
        f"limits: PWM knee ±{first.knee.limit_pct} %, hip ±{first.hip.limit_pct} % (Table 6.1); "
        f"speed knee ±{first.knee.speed_limit_rad_s:.2f}, hip ±{first.hip.speed_limit_rad_s:.2f}"
        " rad/s (gearhead input 6000 rpm)"
    )
    return "\n".join(lines)
