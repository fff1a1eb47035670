"""The Laelaps II leg workspace rule as the master applies it to every write
(``ether_ros.master.workspace``): which variables it covers, the reason it gives, and the hint
when the centre was never set."""

from __future__ import annotations

from ether_ros.master import workspace

OUTPUTS = [
    ("State_Machine", 0x7000, 1),
    ("x_cntr_traj1000", 0x7030, 1),
    ("y_cntr_traj1000", 0x7030, 2),
    ("a_ellipse100", 0x7030, 3),
    ("b_ellipse100", 0x7030, 4),
    ("traj_freq100", 0x7030, 5),
    ("phase_deg", 0x7030, 6),
    ("FlatnessParam100", 0x7030, 7),
]
STANDING = {"y_cntr_traj1000": 599.0, "traj_freq100": 100.0}


def problem(assigned: dict[str, float], current: dict[str, float] | None = None) -> str | None:
    return workspace.leg_write_problem(
        "LaelapsII_Leg", OUTPUTS, STANDING if current is None else current, assigned
    )


def test_only_a_legs_trajectory_record_is_ruled() -> None:
    names = workspace.ruled_outputs("LaelapsII_Leg", OUTPUTS)
    assert names == {name for name, index, _ in OUTPUTS if index == 0x7030}
    assert workspace.ruled_outputs("GenericIO", OUTPUTS) == set()
    assert workspace.leg_write_problem("GenericIO", OUTPUTS, {}, {"a_ellipse100": 99}) is None
    assert problem({"State_Machine": 1}, {}) is None, "not a trajectory variable"


def test_valid_and_invalid_ellipses() -> None:
    assert problem({"b_ellipse100": 4, "a_ellipse100": 5}) is None
    why = problem({"a_ellipse100": 20})
    assert why is not None and why.startswith(
        "a_ellipse100=20 makes an invalid ellipse: toe point (200.0, 599.0) mm, 631.5 mm"
    )
    assert "negative semi-axis" in (problem({"b_ellipse100": -1}) or "")
    assert "frequency 20 Hz" in (problem({"traj_freq100": 2000}) or "")


def test_a_centre_never_set_says_what_to_set_first() -> None:
    assert problem({"a_ellipse100": 5}, {}) == (
        "a_ellipse100=5 makes an invalid ellipse: y_cntr_traj1000 is 0: set the centre first, "
        "e.g. y_cntr_traj1000=599"
    )
    # Setting the centre itself to a bad value gets the geometric reason instead.
    assert "outside the leg workspace" in (problem({"y_cntr_traj1000": 650}, {}) or "")
    assert problem({"y_cntr_traj1000": 599}, {}) is None
