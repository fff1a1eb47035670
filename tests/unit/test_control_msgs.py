"""The FollowJointTrajectory interfaces built from interfaces/control_msgs are those of ROS 2
Jazzy's control_msgs (5.x): the same type names and the same type hashes (REP 2011, RIHS01),
which the middleware compares when MoveIt's or rqt's action client meets the node's server. The
expected hashes are the upstream package's, as its generated C headers state them."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest

SHARE = Path(sys.prefix) / "share" / "control_msgs"

# control_msgs 5.x as released for Jazzy (rosidl_generator_c type hashes of its build).
UPSTREAM = {
    "control_msgs/msg/JointTolerance": (
        "RIHS01_c254f9cece0f3b733017b6990fd46d1326e25242d6b8844398c97d9a88e7d648"
    ),
    "control_msgs/msg/JointComponentTolerance": (
        "RIHS01_739ea7566931944d33830fa10f1bf5e7a7fbdc3172bce7a7eaac642bd6e3ffa4"
    ),
    "control_msgs/action/FollowJointTrajectory": (
        "RIHS01_738ebcb7a2d7cfa42f9f1001cc99ce3a4383d1cfe508015d9be8485e4b1c66f6"
    ),
}


def _hash(kind: str, name: str) -> str:
    description = json.loads((SHARE / kind / f"{name}.json").read_text())
    wanted = f"control_msgs/{kind}/{name}"
    return next(h["hash_string"] for h in description["type_hashes"] if h["type_name"] == wanted)


@pytest.mark.parametrize("type_name", sorted(UPSTREAM))
def test_the_built_interfaces_hash_like_jazzys_control_msgs(type_name: str) -> None:
    _package, kind, name = type_name.split("/")
    assert _hash(kind, name) == UPSTREAM[type_name]


def test_the_action_has_the_fields_and_codes_moveit_uses() -> None:
    from control_msgs.action import FollowJointTrajectory

    goal = FollowJointTrajectory.Goal()
    for field in ("trajectory", "path_tolerance", "goal_tolerance", "goal_time_tolerance"):
        assert hasattr(goal, field)
    codes = FollowJointTrajectory.Result
    assert (codes.SUCCESSFUL, codes.INVALID_GOAL, codes.INVALID_JOINTS) == (0, -1, -2)
    assert (codes.OLD_HEADER_TIMESTAMP, codes.PATH_TOLERANCE_VIOLATED) == (-3, -4)
    assert codes.GOAL_TOLERANCE_VIOLATED == -5
    feedback = FollowJointTrajectory.Feedback()
    assert all(hasattr(feedback, f) for f in ("desired", "actual", "error", "joint_names"))


def test_the_moveit_controllers_example_names_arm6s_joints_and_a_valid_action() -> None:
    """config/moveit_controllers.yaml (docs/ros.md): the joints are arm6's axes and the action
    name MoveIt calls (<controller>/<action_ns>) is one ros.trajectory_action takes."""
    import yaml

    from ether_ros.config import load_bus_config
    from ether_ros.config.bus import RosConfig

    repo = Path(__file__).resolve().parents[2]
    moveit = yaml.safe_load((repo / "config" / "moveit_controllers.yaml").read_text())
    manager = moveit["moveit_simple_controller_manager"]
    (name,) = manager["controller_names"]
    controller = manager[name]
    assert controller["type"] == "FollowJointTrajectory"
    arm6 = load_bus_config(repo / "config" / "arm6.yaml")
    assert controller["joints"] == [a.name for a in arm6.axis_specs()]
    action = f"{name}/{controller['action_ns']}"
    assert RosConfig(trajectory_action=action).trajectory_action == action
