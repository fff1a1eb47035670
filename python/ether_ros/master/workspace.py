"""Is a Laelaps II trajectory valid? The leg workspace check of thesis eqs. 4.1–4.5.

The firmware disregards trajectory parameters (object 0x7030) whose semi-ellipse leaves the leg's
workspace and keeps serving its last valid point. The master refuses such a write instead
(``Bus.write_many``/``write_all``/``write_slaves`` call :func:`leg_write_problem`), so every path
to the outputs — ``pdo_listener``, ``write_variables``, the console, the Python API — gets the
reason rather than a leg that silently ignores the command. The console runs the same function
on its own view of the outputs to check sequence files before the first step is sent.

The rule is the one the simulated firmware applies (``crates/sim/src/devices/trajectory.rs``):
the toe follows ``x = x_c + a·cos s``, ``y = y_c + b·sin s`` in the swing half (sin s < 0) and
``y = y_c + flatness·b·sin s`` in the stance half; every point must lie below the hip, at a
distance from it within [sqrt(l1² + l2²), l1 + l2] = [430.12, 600] mm (eq. 4.4, with 2 mm of
tolerance beyond the stretched leg: Table 6.1's trot touches 601.08 mm at the ends of its stance
line) and within 45° of the vertical; a, b >= 0, frequency 0..10 Hz, flatness 0..1.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass

L1_M = 0.250
L2_M = 0.350
REACH_MAX_M = L1_M + L2_M
REACH_MIN_M = math.hypot(L1_M, L2_M)
REACH_TOLERANCE_M = 0.002
MAX_FREQ_HZ = 10.0
MAX_TOE_ANGLE_DEG = 45.0
CHECK_SAMPLES = 256
#: A centre height inside the workspace: Table 6.1's front legs (mm), for the hint when the
#: centre was never set.
STANDING_Y_MM = 599

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


def is_laelaps_leg(device: str, outputs: Iterable[tuple[str, int, int]]) -> bool:
    """A Laelaps II leg: its ESI device says so and it maps the trajectory record 0x7030
    (``outputs``: (name, index, subindex) of its output variables)."""
    return "laelaps" in device.lower() and any(i == TRAJECTORY_INDEX for _, i, _ in outputs)


def trajectory_names(outputs: Iterable[tuple[str, int, int]]) -> dict[str, str]:
    """Output variable name -> trajectory field (``x_c``, ``a`` ...) of the 0x7030 record."""
    return {
        name: TRAJECTORY_FIELDS[sub]
        for name, index, sub in outputs
        if index == TRAJECTORY_INDEX and sub in TRAJECTORY_FIELDS
    }


def ruled_outputs(device: str, outputs: Iterable[tuple[str, int, int]]) -> set[str]:
    """The output variables whose writes the master checks against the device's rule (and so
    never leaves to the native command path): a Laelaps II leg's trajectory record."""
    outputs = list(outputs)
    return set(trajectory_names(outputs)) if is_laelaps_leg(device, outputs) else set()


def leg_write_problem(
    device: str,
    outputs: Iterable[tuple[str, int, int]],
    current: Mapping[str, float],
    assigned: Mapping[str, float],
) -> str | None:
    """Why writing ``assigned`` (variable name -> value) to a leg whose outputs are ``current``
    makes a trajectory the firmware would disregard; None when it is fine or not a leg's
    trajectory. A variable missing from ``current`` counts as 0 (the master's output image
    starts zeroed)."""
    outputs = list(outputs)
    if not is_laelaps_leg(device, outputs):
        return None
    names = trajectory_names(outputs)
    if not any(name in names for name in assigned):
        return None
    raw = {
        field: float(assigned.get(name, current.get(name, 0.0))) for name, field in names.items()
    }
    reason = invalid_reason(Ellipse.from_raw(raw))
    if reason is None:
        return None
    shown = ", ".join(f"{name}={value:g}" for name, value in assigned.items())
    centre = next((name for name, field in names.items() if field == "y_c"), None)
    if centre is not None and centre not in assigned and raw["y_c"] == 0:
        reason = f"{centre} is 0: set the centre first, e.g. {centre}={STANDING_Y_MM}"
    return f"{shown} makes an invalid ellipse: {reason}"
