"""The trot of thesis Table 6.1: the output values that make one Laelaps II leg trot.

One table serves every user (the trot and frequency experiments, the pysoem proof and
``ether-ros demo``), so the gains and the gait cannot drift apart between them.
"""

from __future__ import annotations

# Phases: FL 180, FR 0, HL 0, HR 180 (diagonal pairs move together); centre height 599 mm for
# the front legs, 598 mm for the hind legs.
LEG_PHASE_DEG = {"FL": 180, "FR": 0, "HL": 0, "HR": 180}
LEG_Y_CENTRE_MM = {"FL": 599, "FR": 599, "HL": 598, "HR": 598}
# What every leg gets: standing (a = b = 0), 1 Hz, flat, and the controller gains.
TROT_COMMON: dict[str, int] = {
    "x_cntr_traj1000": 0,
    "a_ellipse100": 0,
    "b_ellipse100": 0,
    "traj_freq100": 100,
    "FlatnessParam100": 0,
    "Kp100_knee": 8000,
    "Kd1000_knee": 50,
    "Ki100_knee": 0,
    "Kp100_hip": 8000,
    "Kd1000_hip": 50,
    "Ki100_hip": 0,
    "FilterBandwidth": 20,
}
# The ellipse of the trot itself (cm).
TROT_A_CM = 5
TROT_B_CM = 4


def leg_outputs(leg: str, a_cm: int, b_cm: int, transition_s: int) -> dict[str, int]:
    """The outputs of leg ``leg`` (FL/FR/HL/HR) with ellipse ``a_cm`` × ``b_cm``, reached over
    ``transition_s`` seconds, in trajectory mode (State_Machine 1)."""
    return {
        **TROT_COMMON,
        "y_cntr_traj1000": LEG_Y_CENTRE_MM[leg],
        "phase_deg": LEG_PHASE_DEG[leg],
        "a_ellipse100": a_cm,
        "b_ellipse100": b_cm,
        "Transition_time": transition_s,
        "State_Machine": 1,
    }
