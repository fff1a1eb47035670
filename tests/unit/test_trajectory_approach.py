"""Issue 24 (hand-overs bounded in velocity and acceleration): the check of a trajectory's first
point in the future, the way to it from where the joint is commanded to be — refused when it
needs more than the velocity limit or more than the acceleration limit (``max_acceleration``,
default the deceleration), with a message naming the joint, the distance, the time and the
limit. The engine's joining within the limits is tested in crates/engine/src/cia402.rs; the
whole path in tests/acceptance/test_handover_veth.py."""

from __future__ import annotations

import math
from types import SimpleNamespace
from typing import Any

import pytest

from ether_ros.ros import joints
from ether_ros.ros.bridge import AxisRejected


class Axis:
    """What the check reads of an axis: its status and its configured limits."""

    def __init__(
        self,
        *,
        max_acceleration: float | None = None,
        deceleration: float = math.inf,
        velocity: float = 0.0,
        state: str = "operation_enabled",
    ) -> None:
        self.name = "elbow"
        self.spec = SimpleNamespace(
            config=SimpleNamespace(
                velocity_limit=3.0, max_acceleration=max_acceleration, deceleration=deceleration
            )
        )
        self._status = {
            "state": state,
            "position": 0.0,
            "target_position": 0.0,
            "desired_velocity": velocity,
        }

    def status(self) -> dict[str, Any]:
        return dict(self._status)


def test_a_first_point_within_both_limits_is_accepted() -> None:
    # 0.1 rad in 0.2 s from rest: 5 rad/s² (the least constant acceleration), limit 20.
    joints._check_approach(Axis(max_acceleration=20.0), 0.1, 0.2)
    # No acceleration limit at all (neither max_acceleration nor a deceleration): only the
    # velocity limit counts.
    joints._check_approach(Axis(), 0.5, 0.2)


def test_a_first_point_needing_more_than_the_acceleration_limit_is_refused_naming_it() -> None:
    # 0.5 rad in 0.2 s from rest: 2.5 rad/s on average (within 3) but 25 rad/s².
    with pytest.raises(AxisRejected) as info:
        joints._check_approach(Axis(max_acceleration=20.0), 0.5, 0.2)
    text = str(info.value)
    assert "joint 'elbow'" in text
    assert "lies 0.5 from" in text and "in 0.200 s" in text
    assert "acceleration of 25" in text and "beyond the acceleration limit 20" in text


def test_the_acceleration_limit_defaults_to_the_deceleration() -> None:
    with pytest.raises(AxisRejected, match="beyond the acceleration limit 10"):
        joints._check_approach(Axis(deceleration=10.0), 0.3, 0.2)  # 15 rad/s²
    # An explicit max_acceleration wins over the deceleration.
    joints._check_approach(Axis(max_acceleration=20.0, deceleration=10.0), 0.3, 0.2)


def test_the_commanded_velocity_counts() -> None:
    # Moving at 2 rad/s towards a point 0.4 rad ahead in 0.2 s: no acceleration needed.
    joints._check_approach(Axis(max_acceleration=5.0, velocity=2.0), 0.4, 0.2)
    # The same point while moving away at 2 rad/s: 2·(0.4 + 0.4)/0.04 = 40 rad/s².
    with pytest.raises(AxisRejected, match="moving at -2"):
        joints._check_approach(Axis(max_acceleration=20.0, velocity=-2.0), 0.4, 0.2)


def test_the_velocity_limit_is_still_checked_first() -> None:
    with pytest.raises(AxisRejected, match="beyond the velocity limit"):
        joints._check_approach(Axis(max_acceleration=1e9), 1.0, 0.2)


def test_a_first_point_now_or_past_is_not_checked() -> None:
    # The engine replaces it with the commanded state (docs/ros.md, "Hand-overs").
    joints._check_approach(Axis(max_acceleration=1.0), 1.0, 0.0)
    joints._check_approach(Axis(max_acceleration=1.0), 1.0, -0.5)
