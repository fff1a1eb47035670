"""config/topic_based_ros2_control/ (docs/ros.md, "ros2_control via topic_based_ros2_control"):
the xacro snippet and the controller manager's YAML are well-formed, name exactly arm6's axes,
and point TopicBasedSystem at the topics the node really publishes and subscribes."""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

import yaml

from ether_ros.config.bus import load_bus_config
from ether_ros.ros.node import JOINT_COMMANDS_TOPIC, JOINT_STATES_TOPIC

REPO = Path(__file__).resolve().parents[2]
HERE = REPO / "config" / "topic_based_ros2_control"
XACRO_NS = "{http://www.ros.org/wiki/xacro}"


def _arm6_axes() -> list[str]:
    cfg = load_bus_config(REPO / "config" / "arm6.yaml")
    return [a.name for s in cfg.slaves for a in s.axes]


def _macro(root: ET.Element, name: str) -> ET.Element:
    found = [m for m in root.iter(f"{XACRO_NS}macro") if m.get("name") == name]
    assert len(found) == 1, f"one xacro:macro {name}"
    return found[0]


def test_xacro_points_topic_based_system_at_the_nodes_topics() -> None:
    root = ET.parse(HERE / "arm6.ros2_control.xacro").getroot()
    macro = _macro(root, "arm6_ros2_control")
    ns = macro.get("params", "")
    assert ns == "ns:=/arm6"  # the namespace docs/ros.md tells the node to run in
    (system,) = macro.iter("ros2_control")
    assert system.get("type") == "system"
    hw = system.find("hardware")
    assert hw is not None
    assert (hw.findtext("plugin") or "").strip() == "topic_based_ros2_control/TopicBasedSystem"
    params = {p.get("name"): (p.text or "").strip() for p in hw.iter("param")}
    assert params["joint_commands_topic"] == "${ns}/" + JOINT_COMMANDS_TOPIC
    assert params["joint_states_topic"] == "${ns}/" + JOINT_STATES_TOPIC
    # Nothing moves unasked: the first commands are the measured states, not 0.0.
    assert params["use_initial_states_as_initial_commands"] == "true"
    # Commands keep coming while the arm holds still (the node's command watchdog).
    assert float(params["trigger_joint_command_threshold"]) == 0.0


def test_xacro_joints_are_arm6s_axes_with_position_commands() -> None:
    root = ET.parse(HERE / "arm6.ros2_control.xacro").getroot()
    macro = _macro(root, "arm6_ros2_control")
    joints = [j.get("name") for j in macro.iter(f"{XACRO_NS}arm6_joint")]
    assert joints == _arm6_axes()
    joint = _macro(root, "arm6_joint").find("joint")
    assert joint is not None and joint.get("name") == "${name}"
    # arm6 runs in csp: the node takes each joint's position array (docs/ros.md, "Joints").
    assert [c.get("name") for c in joint.iter("command_interface")] == ["position"]
    assert [s.get("name") for s in joint.iter("state_interface")] == [
        "position",
        "velocity",
        "effort",
    ]


def test_controllers_yaml_drives_arm6s_axes() -> None:
    doc = yaml.safe_load((HERE / "arm6_controllers.yaml").read_text())
    manager = doc["controller_manager"]["ros__parameters"]
    assert manager["update_rate"] > 0
    assert (
        manager["arm6_controller"]["type"]
        == "joint_trajectory_controller/JointTrajectoryController"
    )
    assert (
        manager["arm6_position_controller"]["type"]
        == "forward_command_controller/ForwardCommandController"
    )
    assert (
        manager["joint_state_broadcaster"]["type"]
        == "joint_state_broadcaster/JointStateBroadcaster"
    )
    axes = _arm6_axes()
    jtc = doc["arm6_controller"]["ros__parameters"]
    assert jtc["joints"] == axes and jtc["command_interfaces"] == ["position"]
    fwd = doc["arm6_position_controller"]["ros__parameters"]
    assert fwd["joints"] == axes and fwd["interface_name"] == "position"
