"""Is a Laelaps II trajectory valid? The leg workspace check of thesis eqs. 4.1–4.5.

The firmware disregards trajectory parameters (object 0x7030) whose semi-ellipse leaves the leg's
workspace and keeps serving its last valid point. The console checks the same rule first, so an
operator gets the reason instead of a leg that silently ignores the command.

The rule is the one the simulated firmware applies (``crates/sim/src/devices/trajectory.rs``):
the toe follows ``x = x_c + a·cos s``, ``y = y_c + b·sin s`` in the swing half (sin s < 0) and
``y = y_c + flatness·b·sin s`` in the stance half; every point must lie below the hip, at a
distance from it within [sqrt(l1² + l2²), l1 + l2] = [430.12, 600] mm (eq. 4.4, with 2 mm of
tolerance beyond the stretched leg: Table 6.1's trot touches 601.08 mm at the ends of its stance
line) and within 45° of the vertical; a, b >= 0, frequency 0..10 Hz, flatness 0..1.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

L1_M = 0.250
L2_M = 0.350
REACH_MAX_M = L1_M + L2_M
REACH_MIN_M = math.hypot(L1_M, L2_M)
REACH_TOLERANCE_M = 0.002
MAX_FREQ_HZ = 10.0
MAX_TOE_ANGLE_DEG = 45.0
CHECK_SAMPLES = 256

# Trajectory record 0x7030: subindex -> (what it is, scale from the raw integer to SI)
TRAJECTORY_INDEX = 0x7030
TRAJECTORY_FIELDS: dict[int, str] = {
    1: "x_c",  # mm
    2: "y_c",  # mm
    3: "a",  # cm
    4: "b",  # cm
    5: "freq",  # Hz / 100
    6: "phase",  # deg
    7: "flatness",  # / 100
}


@dataclass(frozen=True)
class Ellipse:
    """Trajectory parameters in SI units (m, Hz, rad, fraction)."""

    x_c: float
    y_c: float
    a: float
    b: float
    freq_hz: float = 1.0
    phase_rad: float = 0.0
    flatness: float = 0.0

    @classmethod
    def from_raw(cls, raw: Mapping[str, float]) -> Ellipse:
        """From the raw 0x7030 values keyed like :data:`TRAJECTORY_FIELDS`."""
        return cls(
            x_c=raw.get("x_c", 0.0) / 1000.0,
            y_c=raw.get("y_c", 0.0) / 1000.0,
            a=raw.get("a", 0.0) / 100.0,
            b=raw.get("b", 0.0) / 100.0,
            freq_hz=raw.get("freq", 0.0) / 100.0,
            phase_rad=math.radians(raw.get("phase", 0.0)),
            flatness=raw.get("flatness", 0.0) / 100.0,
        )

    def point_at(self, s: float) -> tuple[float, float]:
        sin = math.sin(s)
        lift = 1.0 if sin < 0.0 else self.flatness
        return self.x_c + self.a * math.cos(s), self.y_c + lift * self.b * sin


def invalid_reason(e: Ellipse) -> str | None:
    """Why the ellipse is invalid, or None when the firmware will accept it."""
    if e.a < 0 or e.b < 0:
        return f"negative semi-axis (a {e.a * 100:g} cm, b {e.b * 100:g} cm)"
    if not 0.0 <= e.freq_hz <= MAX_FREQ_HZ:
        return f"trajectory frequency {e.freq_hz:g} Hz outside 0..{MAX_FREQ_HZ:g} Hz"
    if not 0.0 <= e.flatness <= 1.0:
        return f"flatness {e.flatness:g} outside 0..1"
    max_tan = math.tan(math.radians(MAX_TOE_ANGLE_DEG))
    for i in range(CHECK_SAMPLES):
        x, y = e.point_at(2 * math.pi * i / CHECK_SAMPLES)
        reach = math.hypot(x, y)
        if y <= 0 or not (
            REACH_MIN_M - REACH_TOLERANCE_M <= reach <= REACH_MAX_M + REACH_TOLERANCE_M
        ):
            return (
                f"toe point ({x * 1e3:.1f}, {y * 1e3:.1f}) mm, {reach * 1e3:.1f} mm from the hip, "
                f"is outside the leg workspace {REACH_MIN_M * 1e3:.2f}..{REACH_MAX_M * 1e3:.0f} mm"
            )
        if abs(x) > y * max_tan:
            return (
                f"toe point ({x * 1e3:.1f}, {y * 1e3:.1f}) mm is more than "
                f"{MAX_TOE_ANGLE_DEG:g}° from the vertical"
            )
    return None
