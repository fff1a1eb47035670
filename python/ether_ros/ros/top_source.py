"""``ether-ros top`` on the running node: the live view's source that reads the node's
diagnostics, bus layout and joint extras over ROS 2, with a panic line of its own.

The screen and its snapshot types are the tools' (``ether_ros.tools.live``); this source lives
beside the node it reads, so the arrow runs ros → tools and never back (docs/architecture.md,
"Layers"). The node's reports age: one older than two of its periods is shown as stale — slave
states unknown, never the OP of a node that is gone.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from ether_ros.ros.freshness import Arrivals, describe_age
from ether_ros.tools.live import LiveSnapshot, snapshot_from_diagnostics

if TYPE_CHECKING:
    from ether_ros.ros.panic_line import PanicLine


class DiagnosticsLiveSource:
    """The running node: subscribes to its diagnostics and shows the newest statuses."""

    def __init__(
        self,
        topic: str = "/diagnostics",
        node_name: str = "ether_ros_top",
        layout_topic: str = "/bus_layout",
    ) -> None:
        try:
            import rclpy
            from diagnostic_msgs.msg import DiagnosticArray
        except ImportError as exc:
            from ether_ros.errors import EtherRosError

            raise EtherRosError(
                "ROS 2 (rclpy, diagnostic_msgs) is not available: source the "
                "ROS 2 setup, or use --config CFG --interface IFACE for a "
                "standalone bus"
            ) from exc
        self._rclpy = rclpy
        self._owns_context = not rclpy.ok()
        if self._owns_context:
            rclpy.init()
        self._node = rclpy.create_node(node_name)
        # The node's services live beside its diagnostics topic ("/robot/diagnostics":
        # "/robot/panic").
        from ether_ros.ros.panic_line import PanicLine  # rclpy: only once it is known there

        self._panic_line = PanicLine(
            topic[: topic.rfind("/") + 1],
            self._node.context,
            hint="clear it from the console ('clear')",
        )
        self.arrivals = Arrivals()
        self._master: dict[str, str] | None = None
        self._node_name = ""
        self._slaves: dict[str, tuple[str, dict[str, str]]] = {}
        self._axes: dict[str, dict[str, str]] = {}
        self._groups: dict[str, dict[str, str]] = {}
        self._node.create_subscription(DiagnosticArray, topic, self._on_message, 10)
        self._bus_name = ""
        self._cycle_us = 0
        self._subscribe_layout(layout_topic)
        # joint -> extra -> value (SI), from the node's joint_extras beside its diagnostics.
        self._extras: dict[str, dict[str, float]] = {}
        self._subscribe_extras(topic[: topic.rfind("/") + 1] + "joint_extras")

    def _subscribe_extras(self, topic: str) -> None:
        try:
            from ether_ros_msgs.msg import JointExtras
        except ImportError:
            return  # the messages are not built: the view goes without the extras
        self._node.create_subscription(JointExtras, topic, self._on_extras, 10)

    def _on_extras(self, msg: Any) -> None:
        self._extras = extras_by_joint(msg)

    def _subscribe_layout(self, topic: str) -> None:
        """The node's latched bus layout gives the bus name and cycle time."""
        try:
            from ether_ros_msgs.msg import BusLayout
            from rclpy.qos import DurabilityPolicy, QoSProfile
        except ImportError:
            return  # the messages are not built: the view goes without the cycle time
        qos = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL)
        self._node.create_subscription(BusLayout, topic, self._on_layout, qos)

    def _on_layout(self, msg: Any) -> None:
        self._bus_name, self._cycle_us = str(msg.bus), int(msg.cycle_us)

    def _on_message(self, msg: Any) -> None:
        for status in msg.status:
            node, sep, what = status.name.partition(": ")
            if not sep:
                continue
            values = {kv.key: kv.value for kv in status.values}
            if what == "master":
                self._master, self._node_name = values, node.lstrip("/")
                self.arrivals.note("diagnostics")
            elif what.startswith("slave "):
                self._slaves[what[len("slave ") :]] = (status.message, values)
            elif what.startswith("axis "):
                self._axes[what[len("axis ") :]] = values
            elif what.startswith("group "):
                self._groups[what[len("group ") :]] = values

    def poll(self) -> LiveSnapshot:
        self._panic_line.claim_keys()  # a key the screen did not see as one is still answered
        self._rclpy.spin_once(self._node, timeout_sec=0.0)
        if self._master is None:
            return LiveSnapshot(
                source="ROS 2 diagnostics", error="waiting for the node's diagnostics"
            )
        snap = snapshot_from_diagnostics(
            self._master,
            self._slaves,
            self._bus_name,
            axes=self._axes,
            groups=self._groups,
            extras=self._extras,
        )
        snap.cycle_us = self._cycle_us
        snap.source = f"node {self._node_name}, {snap.source}"
        if not self.arrivals.fresh("diagnostics"):
            mark_stale(snap, self._node_name, self.arrivals)
        return snap

    @property
    def panic_line(self) -> PanicLine:
        return self._panic_line

    def panic(self, report: Callable[[str], None]) -> None:
        self._panic_line.report = report
        if self._panic_line.watching:
            self._panic_line.claim_keys()  # the native key reader has sent it already
        else:
            self._panic_line.press()

    def close(self) -> None:
        self._panic_line.close()
        self._node.destroy_node()
        if self._owns_context and self._rclpy.ok():
            self._rclpy.shutdown()


def extras_by_joint(msg: Any) -> dict[str, dict[str, float]]:
    """joint -> extra -> value from a ``JointExtras`` message (its parallel arrays; a message
    whose arrays differ in length gives nothing rather than a wrong pairing)."""
    joints, names, values = list(msg.joints), list(msg.names), list(msg.values)
    if not len(joints) == len(names) == len(values):
        return {}
    out: dict[str, dict[str, float]] = {}
    for joint, name, value in zip(joints, names, values, strict=True):
        out.setdefault(joint, {})[name] = float(value)
    return out


def mark_stale(snap: LiveSnapshot, node: str, arrivals: Arrivals) -> None:
    """The node's last report is older than two periods: say so, and show no slave state
    (a node that is gone has no slaves in OP, whatever its last report said)."""
    age = arrivals.age("diagnostics") or 0.0
    snap.stale = (
        f"no report from node {node or '?'} for {describe_age(age)} (it reports every "
        f"{describe_age(arrivals.period('diagnostics'))}): the node is gone or stalled; "
        "nothing below is current"
    )
    for row in snap.slaves:
        row.state, row.detail = "?", f"unknown: no report for {describe_age(age)}"
    for axis in snap.axes:
        axis.state = "?"
