"""A ROS 2 client of the ether_ros node: what the console, the demo, the tests and the
benchmarks use to operate a running node over ROS 2 only.

It is an ordinary rclpy node spun by its own executor thread. It calls the node's services
(commands, writes, SDO, lifecycle transitions) and keeps the latest message of each topic (layout,
decoded inputs/outputs per slave, joint states, diagnostics, write results) so callers can read
them or wait for a condition on them.

The control lease (docs/security.md): with ``lease="auto"`` (the default) the client asks the
node once whether its lease is on and, if so, acquires it before its first command (never taking
it from another holder) and keeps it alive from a thread of its own; its command publishers are
registered as the holder's. ``lease="manual"`` leaves that to :meth:`acquire_lease` /
:meth:`release_lease`; ``panic`` never needs it.
"""

from __future__ import annotations

import contextlib
import itertools
import json
import logging
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, TypeVar

import rclpy
import rclpy.executors
from builtin_interfaces.msg import Duration
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from ether_ros_msgs.msg import (
    BusLayout,
    JointExtras,
    PdoRaw,
    SlaveValues,
    WriteResult,
    WriteVariable,
)
from ether_ros_msgs.srv import (
    AxisCommand,
    Command,
    Lease,
    SdoRead,
    SdoWrite,
    SetExtras,
    SetMode,
    WriteVariables,
)
from lifecycle_msgs.msg import Transition
from lifecycle_msgs.srv import ChangeState, GetState
from rcl_interfaces.msg import Parameter as ParameterMsg
from rcl_interfaces.srv import GetParameters, SetParameters
from rclpy.context import Context
from rclpy.parameter import Parameter
from sensor_msgs.msg import JointState
from std_srvs.srv import Trigger
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

from ether_ros.errors import EtherRosError
from ether_ros.ros.bridge import AXIS_SERVICES
from ether_ros.ros.convert import spec_from_msg
from ether_ros.ros.freshness import Arrivals
from ether_ros.ros.layout import BusSpec
from ether_ros.ros.lease import own_goal_reply_gids, own_publisher_gids
from ether_ros.ros.node import (
    COMMAND_TOPICS,
    QOS_COMMANDS,
    QOS_HIGH_RATE,
    QOS_LATCHED,
    QOS_RELIABLE,
    QOS_RESULTS,
)

T = TypeVar("T")
log = logging.getLogger(__name__)

# Transitions ``ethercat_communicator`` runs by name, with the lease: the lifecycle
# transition -> the command (the three shutdowns are one command, from whatever state).
LEASED_TRANSITIONS = {
    "configure": "configure",
    "activate": "activate",
    "deactivate": "deactivate",
    "cleanup": "cleanup",
    "shutdown": "shutdown",
    "inactive_shutdown": "shutdown",
    "active_shutdown": "shutdown",
}

TRANSITIONS = {
    "configure": Transition.TRANSITION_CONFIGURE,
    "cleanup": Transition.TRANSITION_CLEANUP,
    "activate": Transition.TRANSITION_ACTIVATE,
    "deactivate": Transition.TRANSITION_DEACTIVATE,
    "shutdown": Transition.TRANSITION_UNCONFIGURED_SHUTDOWN,
    "inactive_shutdown": Transition.TRANSITION_INACTIVE_SHUTDOWN,
    "active_shutdown": Transition.TRANSITION_ACTIVE_SHUTDOWN,
}


class ClientError(EtherRosError):
    """The node did not answer (not running, wrong name or namespace, timeout)."""


class Answer(tuple[bool, str]):
    """A service's answer: unpacks as ``(success, message)`` as before, and carries the
    ``error`` and ``code`` fields of the response (docs/ros.md, "Error codes"): the typed
    error's class and its code as data — SDO abort code, AL status code, mailbox error code."""

    error: str
    code: int

    def __new__(cls, success: bool, message: str, error: str = "", code: int = 0) -> Answer:
        answer = super().__new__(cls, (success, message))
        answer.error, answer.code = error, code
        return answer

    @classmethod
    def of(cls, resp: Any) -> Answer:
        return cls(bool(resp.success), str(resp.message), str(resp.error), int(resp.code))

    @property
    def success(self) -> bool:
        return self[0]

    @property
    def message(self) -> str:
        return self[1]


# A diagnostic status level as the word every tool prints (diagnostic_msgs/DiagnosticStatus).
LEVEL_WORDS = {
    int.from_bytes(DiagnosticStatus.OK, "little"): "OK",
    int.from_bytes(DiagnosticStatus.WARN, "little"): "WARN",
    int.from_bytes(DiagnosticStatus.ERROR, "little"): "ERROR",
    int.from_bytes(DiagnosticStatus.STALE, "little"): "STALE",
}


def level_word(level: bytes) -> str:
    """``b"\\x01"`` -> ``"WARN"`` (an unknown level as its number)."""
    number = int.from_bytes(level, "little")
    return LEVEL_WORDS.get(number, str(number))


@dataclass
class Latest:
    """The latest values of the node's topics, as the client last received them."""

    layout: BusSpec | None = None
    inputs: dict[str, dict[str, float]] = field(default_factory=dict)
    outputs: dict[str, dict[str, float]] = field(default_factory=dict)  # echo of the wire
    commanded: dict[str, dict[str, float]] = field(default_factory=dict)  # pdo_out_timer
    joint_state: JointState | None = None
    joint_extras: JointExtras | None = None
    diagnostics: DiagnosticArray | None = None
    raw: PdoRaw | None = None
    counts: dict[str, int] = field(default_factory=dict)
    # When each report arrived ("diagnostics", "inputs/<slave>", "outputs/<slave>",
    # "commanded/<slave>"): a screen marks a report older than two periods as stale.
    arrivals: Arrivals = field(default_factory=Arrivals)


class EtherRosClient:
    def __init__(
        self,
        node_name: str = "ether_comm",
        namespace: str = "",
        client_name: str | None = None,
        context: Context | None = None,
        raw: bool = False,
        on_joint_state: Callable[[JointState], None] | None = None,
        on_inputs: Callable[[SlaveValues], None] | None = None,
        on_outputs: Callable[[SlaveValues], None] | None = None,
        lease: str = "auto",
        lease_ttl_s: float = 0.0,
        lease_writers: list[str] | None = None,
    ) -> None:
        if lease not in ("auto", "manual"):
            raise ClientError(f"lease: 'auto' or 'manual', got {lease!r}")
        self._own_context = context is None and not rclpy.ok()
        if self._own_context:
            rclpy.init()
        self._context = context
        ns = namespace.rstrip("/")
        self.prefix = f"{ns}/" if ns else ""
        self.target = f"{ns}/{node_name}" if ns else f"/{node_name}"
        name = client_name or f"ether_ros_client_{_unique()}"
        self.node = rclpy.create_node(name, context=context)
        self.latest = Latest()
        self.results: deque[WriteResult] = deque(maxlen=1000)
        self.joint_results: deque[WriteResult] = deque(maxlen=1000)
        self._cond = threading.Condition()
        self._on_joint_state = on_joint_state
        self._on_inputs = on_inputs
        self._on_outputs = on_outputs
        self._request_ids = itertools.count(1)
        n, p = self.node, self.prefix
        self._command = n.create_client(Command, f"{p}ethercat_communicator")
        self._panic = n.create_client(Trigger, f"{p}panic")
        self._writes = n.create_client(WriteVariables, f"{p}write_variables")
        self._sdo_read = n.create_client(SdoRead, f"{p}sdo_read")
        self._sdo_write = n.create_client(SdoWrite, f"{p}sdo_write")
        self._change_state = n.create_client(ChangeState, f"{self.target}/change_state")
        self._get_state = n.create_client(GetState, f"{self.target}/get_state")
        self._write_pub = n.create_publisher(WriteVariable, f"{p}pdo_listener", QOS_COMMANDS)
        self._axis = {c: n.create_client(AxisCommand, f"{p}{c}") for c in AXIS_SERVICES}
        self._set_mode = n.create_client(SetMode, f"{p}set_mode")
        self._set_extras = n.create_client(SetExtras, f"{p}set_extras")
        self._joint_pub = n.create_publisher(JointState, f"{p}joint_commands", QOS_COMMANDS)
        self._trajectory_pub = n.create_publisher(
            JointTrajectory, f"{p}joint_trajectory", QOS_COMMANDS
        )
        self._lease_client = n.create_client(Lease, f"{p}lease")
        self._lease_mode = lease
        self._lease_ttl_s = float(lease_ttl_s)
        #: Other nodes (full names) whose command publishers count as this client's while it
        #: holds the lease (e.g. a controller node it runs).
        self.lease_writers = list(lease_writers or [])
        self._lease_lock = threading.RLock()
        #: The lease token held (0: none), whether the node's lease is on (None: not asked yet)
        #: and why the last renewal failed ("" while it holds).
        self.lease_token = 0
        self.lease_enabled: bool | None = None
        self.lease_lost = ""
        self._lease_ttl_granted = 0.0
        self._keeper: threading.Thread | None = None
        self._keeper_stop = threading.Event()
        self._closing = threading.Event()  # close() has begun: the spin thread ends
        n.create_subscription(BusLayout, f"{p}bus_layout", self._on_layout, QOS_LATCHED)
        n.create_subscription(SlaveValues, f"{p}pdo_in", self._on_values("inputs"), QOS_HIGH_RATE)
        n.create_subscription(SlaveValues, f"{p}pdo_out", self._on_values("outputs"), QOS_HIGH_RATE)
        n.create_subscription(
            SlaveValues, f"{p}pdo_out_timer", self._on_values("commanded"), QOS_RELIABLE
        )
        n.create_subscription(JointState, f"{p}joint_states", self._on_joints, QOS_RELIABLE)
        n.create_subscription(JointExtras, f"{p}joint_extras", self._on_extras, QOS_RELIABLE)
        n.create_subscription(DiagnosticArray, f"{p}diagnostics", self._on_diag, QOS_RELIABLE)
        n.create_subscription(WriteResult, f"{p}write_results", self._on_result, QOS_RESULTS)
        n.create_subscription(WriteResult, f"{p}joint_results", self._on_joint_result, QOS_RESULTS)
        if raw:
            n.create_subscription(PdoRaw, f"{p}pdo_raw", self._on_raw, QOS_HIGH_RATE)
        self._executor = rclpy.executors.SingleThreadedExecutor(context=context)
        self._executor.add_node(self.node)
        self._thread = threading.Thread(target=self._spin, name="ether_ros-client", daemon=True)
        self._thread.start()

    def _spin(self) -> None:
        """Spin until the client closes or the context shuts down. One wait at a time, so that
        an error in one (an entity destroyed from another thread while the executor waited on
        it, e.g. an action client's ``destroy()``) does not end the thread: every message after
        it would be lost and the client would wait for the node in vain."""
        while not self._closing.is_set() and self._executor.context.ok():
            try:
                self._executor.spin_once(timeout_sec=0.2)
            except (
                rclpy.executors.ShutdownException,
                rclpy.executors.ExternalShutdownException,
            ):
                return
            except Exception as exc:  # see above; closing or a shut-down context ends the loop
                log.debug("client executor: %s (spinning on)", exc)

    def close(self) -> None:
        self._closing.set()
        self._keeper_stop.set()
        if self._keeper is not None:
            self._keeper.join(timeout=2)
        if self.lease_token:
            with contextlib.suppress(Exception):  # the node may be gone already
                self.release_lease(timeout=1.0)
        self._executor.shutdown(timeout_sec=5.0)
        # The spin thread must be out of the executor's wait before the node's handles go:
        # destroying the node first crashed rclpy (a segfault in wait_for_ready_callbacks) when
        # a loaded host made the shutdown slower than its timeout.
        self._thread.join(timeout=5)
        if not self._thread.is_alive():
            self.node.destroy_node()
        if self._own_context and rclpy.ok():
            rclpy.try_shutdown()

    def __enter__(self) -> EtherRosClient:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ------------------------------------------------------------------------ topics
    def _bump(self, name: str) -> None:
        self.latest.counts[name] = self.latest.counts.get(name, 0) + 1

    def _on_layout(self, msg: BusLayout) -> None:
        with self._cond:
            self.latest.layout = spec_from_msg(msg)
            self._bump("bus_layout")
            self._cond.notify_all()

    def _on_values(self, kind: str) -> Callable[[SlaveValues], None]:
        def handle(msg: SlaveValues) -> None:
            with self._cond:
                layout = self.latest.layout
                if layout is not None:
                    try:
                        slave = layout.slave(msg.slave)
                    except EtherRosError:
                        return
                    names = slave.inputs if kind == "inputs" else slave.outputs
                    if len(names) == len(msg.values):
                        target: dict[str, dict[str, float]] = getattr(self.latest, kind)
                        target[msg.slave] = {
                            v.name: float(x) for v, x in zip(names, msg.values, strict=True)
                        }
                        self.latest.arrivals.note(f"{kind}/{msg.slave}")
                self._bump(kind)
                self._cond.notify_all()
            if kind == "inputs" and self._on_inputs is not None:
                self._on_inputs(msg)
            if kind == "outputs" and self._on_outputs is not None:
                self._on_outputs(msg)

        return handle

    def forget_commanded(self) -> None:
        """Drop the commanded outputs received so far (``pdo_out_timer``): after a clear_panic
        the node has reset them to the safe values, and a snapshot from before it must not
        be taken for the current state; the next snapshots bring them again."""
        with self._cond:
            self.latest.commanded.clear()
            self._cond.notify_all()

    def _on_joints(self, msg: JointState) -> None:
        with self._cond:
            self.latest.joint_state = msg
            self._bump("joint_states")
            self._cond.notify_all()
        if self._on_joint_state is not None:
            self._on_joint_state(msg)

    def _on_extras(self, msg: JointExtras) -> None:
        with self._cond:
            self.latest.joint_extras = msg
            self._bump("joint_extras")
            self._cond.notify_all()

    def _on_diag(self, msg: DiagnosticArray) -> None:
        with self._cond:
            self.latest.diagnostics = msg
            self.latest.arrivals.note("diagnostics")
            self._bump("diagnostics")
            self._cond.notify_all()

    def _on_result(self, msg: WriteResult) -> None:
        with self._cond:
            self.results.append(msg)
            self._bump("write_results")
            self._cond.notify_all()

    def _on_joint_result(self, msg: WriteResult) -> None:
        with self._cond:
            self.joint_results.append(msg)
            self._bump("joint_results")
            self._cond.notify_all()

    def _on_raw(self, msg: PdoRaw) -> None:
        with self._cond:
            self.latest.raw = msg
            self._bump("pdo_raw")
            self._cond.notify_all()

    def wait_for(self, predicate: Callable[[Latest], T], timeout: float = 5.0) -> T:
        """Wait until ``predicate(latest)`` is truthy and return it; ClientError on timeout."""
        deadline = time.monotonic() + timeout
        with self._cond:
            while True:
                value = predicate(self.latest)
                if value:
                    return value
                left = deadline - time.monotonic()
                if left <= 0:
                    raise ClientError(f"timed out after {timeout:g} s waiting for the node")
                self._cond.wait(min(left, 0.1))

    def layout(self, timeout: float = 5.0) -> BusSpec:
        layout = self.wait_for(lambda latest: latest.layout, timeout)
        assert layout is not None
        return layout

    def master_status(self) -> dict[str, str]:
        """Key/values of the master's diagnostic status (empty before the first report)."""
        diag = self.latest.diagnostics
        if diag is None:
            return {}
        for st in diag.status:
            if st.name.endswith(": master"):
                values = {kv.key: kv.value for kv in st.values}
                values["message"] = st.message
                values["level"] = level_word(st.level)
                return values
        return {}

    def slave_states(self) -> dict[str, str]:
        diag = self.latest.diagnostics
        out: dict[str, str] = {}
        if diag is None:
            return out
        for st in diag.status:
            if ": slave " in st.name:
                out[st.name.split(": slave ", 1)[1]] = st.message
        return out

    # ------------------------------------------------------------------------ services
    def _call(self, client: Any, request: Any, timeout: float) -> Any:
        if not client.wait_for_service(timeout_sec=timeout):
            raise ClientError(
                f"service {client.srv_name} is not available (is the node {self.target} running?)"
            )
        future = client.call_async(request)
        done = threading.Event()
        future.add_done_callback(lambda _f: done.set())
        if not done.wait(timeout):
            client.remove_pending_request(future)
            raise ClientError(f"service {client.srv_name} did not answer within {timeout:g} s")
        return future.result()

    def command(self, command: str, timeout: float = 30.0) -> Answer:
        """(success, message); a refused state change carries the AL status code in
        ``.code`` (``.error`` ``"AlStateRefused"``)."""
        token = 0 if command.strip().lower() == "panic" else self._token()
        req = Command.Request(command=command, lease=token)
        return Answer.of(self._call(self._command, req, timeout))

    def panic(self, timeout: float = 5.0) -> tuple[bool, str]:
        resp = self._call(self._panic, Trigger.Request(), timeout)
        return bool(resp.success), str(resp.message)

    def write_many(self, writes: list[WriteVariable], timeout: float = 5.0) -> Answer:
        """All-or-nothing: the node validates every write before applying any. A refusal
        carries the typed error's class in ``.error`` (and its code, if it has one)."""
        req = WriteVariables.Request(writes=writes, lease=self._token())
        return Answer.of(self._call(self._writes, req, timeout))

    def write(
        self, slave: str | int, variable: str, value: float | str, timeout: float = 5.0
    ) -> Answer:
        return self.write_many([make_write(slave, variable, value)], timeout)

    def publish_write(self, slave: str | int, variable: str, value: float | str) -> int:
        """Fire-and-forget on ``pdo_listener``; the answer comes on ``write_results`` with the
        returned request id."""
        msg = make_write(slave, variable, value)
        msg.request_id = next(self._request_ids)
        self._token()
        self._write_pub.publish(msg)
        return int(msg.request_id)

    def wait_result(self, request_id: int, timeout: float = 5.0) -> WriteResult:
        def find(_latest: Latest) -> WriteResult | None:
            for r in self.results:
                if r.request_id == request_id:
                    return r
            return None

        return self.wait_for(find, timeout)

    # ------------------------------------------------------------------------ joints
    def axis_command(
        self, command: str, joints: list[str] | None = None, timeout: float = 10.0
    ) -> tuple[bool, str, dict[str, str]]:
        """``enable``, ``disable``, ``reset_fault`` or ``home`` for the joints (None/empty: all):
        (success, message, {joint: CiA 402 state})."""
        if command not in self._axis:
            raise ClientError(f"unknown axis command {command!r} ({', '.join(self._axis)})")
        req = AxisCommand.Request(joints=list(joints or []), lease=self._token())
        resp = self._call(self._axis[command], req, timeout)
        return _axis_answer(resp)

    def set_mode(
        self, mode: str, joints: list[str] | None = None, timeout: float = 10.0
    ) -> tuple[bool, str, dict[str, str]]:
        req = SetMode.Request(joints=list(joints or []), mode=mode, lease=self._token())
        resp = self._call(self._set_mode, req, timeout)
        return _axis_answer(resp)

    def set_extras(
        self, joint: str, values: dict[str, float], timeout: float = 10.0
    ) -> tuple[bool, str]:
        """Command writable extras of one axis in SI units (``set_extras``): (success,
        message)."""
        req = SetExtras.Request(
            joint=joint,
            names=list(values),
            values=[float(v) for v in values.values()],
            lease=self._token(),
        )
        resp = self._call(self._set_extras, req, timeout)
        return bool(resp.success), str(resp.message)

    def publish_joint_command(
        self,
        names: list[str],
        position: list[float] | None = None,
        velocity: list[float] | None = None,
        effort: list[float] | None = None,
    ) -> None:
        """Setpoints on ``joint_commands`` (a refusal comes on ``joint_results``)."""
        msg = JointState()
        msg.header.stamp = self.node.get_clock().now().to_msg()
        msg.name = list(names)
        msg.position = [float(x) for x in position or []]
        msg.velocity = [float(x) for x in velocity or []]
        msg.effort = [float(x) for x in effort or []]
        self._token()
        self._joint_pub.publish(msg)

    def publish_trajectory(
        self,
        names: list[str],
        points: list[tuple[float, list[float]]],
        velocities: list[list[float]] | None = None,
        start: float = 0.0,
    ) -> None:
        """A JointTrajectory: ``points`` are (time_from_start s, positions); ``start`` is the
        header stamp in wall-clock seconds (0: now). The answer comes on ``joint_results``."""
        msg = JointTrajectory()
        if start:
            ns = int(start * 1e9)
            msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(ns, 1_000_000_000)
        msg.joint_names = list(names)
        for i, (t, positions) in enumerate(points):
            p = JointTrajectoryPoint()
            p.positions = [float(x) for x in positions]
            if velocities is not None:
                p.velocities = [float(x) for x in velocities[i]]
            ns = round(t * 1e9)
            p.time_from_start = Duration(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)
            msg.points.append(p)
        self._token()
        self._trajectory_pub.publish(msg)

    def axis_parameters(self, timeout: float = 5.0) -> dict[str, dict[str, Any]]:
        """The axes' configuration as the node mirrors it (``axis_joints``, ``axes.<joint>.*``
        parameters): {joint: {slave, mode, position_limits, velocity_limit, torque_limit}}."""
        joints = self.get_parameters(["axis_joints"], timeout)["axis_joints"] or []
        keys = ("slave", "mode", "position_limits", "velocity_limit", "torque_limit")
        names = [f"axes.{j}.{k}" for j in joints for k in keys]
        values = self.get_parameters(names, timeout) if names else {}
        out = {}
        for j in joints:
            p = {k: values[f"axes.{j}.{k}"] for k in keys}
            p["position_limits"] = tuple(float(x) for x in p["position_limits"])
            out[str(j)] = p
        return out

    def axis_states(self) -> dict[str, dict[str, str]]:
        """Key/values (plus ``message`` and ``level``) of every axis's diagnostic status."""
        diag = self.latest.diagnostics
        out: dict[str, dict[str, str]] = {}
        if diag is None:
            return out
        for st in diag.status:
            if ": axis " in st.name:
                values = {kv.key: kv.value for kv in st.values}
                values["message"] = st.message
                values["level"] = level_word(st.level)
                out[st.name.split(": axis ", 1)[1]] = values
        return out

    def sdo_read(
        self, slave: str, index: int, subindex: int, type_name: str = "", timeout: float = 10.0
    ) -> SdoRead.Response:
        """The response itself: ``success``, ``message``, ``data``, ``value``, and for a
        refusal ``error``/``code`` (an SDO abort: ``"SdoAbort"`` and its abort code)."""
        req = SdoRead.Request(slave=slave, index=index, subindex=subindex, type=type_name)
        return self._call(self._sdo_read, req, timeout)

    def sdo_write(
        self,
        slave: str,
        index: int,
        subindex: int,
        type_name: str,
        value: str,
        timeout: float = 10.0,
    ) -> Answer:
        """(success, message); an SDO abort carries its abort code in ``.code``."""
        req = SdoWrite.Request(
            slave=slave,
            index=index,
            subindex=subindex,
            type=type_name,
            value=value,
            lease=self._token(),
        )
        return Answer.of(self._call(self._sdo_write, req, timeout))

    def change_state(self, transition: str, timeout: float = 30.0) -> bool:
        """A lifecycle transition. While the node's lease is on, its ``change_state`` is
        refused (it carries no lease): the transition goes through ``ethercat_communicator``
        with the lease instead."""
        if transition not in TRANSITIONS:
            raise ClientError(f"unknown transition '{transition}' ({', '.join(TRANSITIONS)})")
        if self._token():
            return self.command(LEASED_TRANSITIONS[transition], timeout)[0]
        req = ChangeState.Request()
        req.transition.id = TRANSITIONS[transition]
        return bool(self._call(self._change_state, req, timeout).success)

    def get_state(self, timeout: float = 5.0) -> str:
        return str(self._call(self._get_state, GetState.Request(), timeout).current_state.label)

    def get_parameters(self, names: list[str], timeout: float = 5.0) -> dict[str, Any]:
        """The node's parameters by name (None for an undeclared one)."""
        client = self.node.create_client(GetParameters, f"{self.target}/get_parameters")
        try:
            resp = self._call(client, GetParameters.Request(names=names), timeout)
            values = list(resp.values)
            if len(values) != len(names):
                # rclpy leaves undeclared names out of the answer: ask name by name.
                values = []
                for name in names:
                    one = self._call(client, GetParameters.Request(names=[name]), timeout)
                    values.append(one.values[0] if one.values else None)
        finally:
            self.node.destroy_client(client)
        return {
            n: None
            if v is None
            else Parameter.from_parameter_msg(ParameterMsg(name=n, value=v)).value
            for n, v in zip(names, values, strict=True)
        }

    def set_parameter(self, name: str, value: Any, timeout: float = 5.0) -> tuple[bool, str]:
        """Set one of the node's parameters: (success, reason). While the node's lease is on,
        the standard ``set_parameters`` service refuses every write (it cannot tell who calls
        it), so the write goes through ``ethercat_communicator`` with the lease token
        (``set_parameter NAME VALUE``, docs/security.md)."""
        if self._token():
            return self.command(f"set_parameter {name} {json.dumps(value)}", timeout)
        client = self.node.create_client(SetParameters, f"{self.target}/set_parameters")
        try:
            msg = Parameter(name, value=value).to_parameter_msg()
            req = SetParameters.Request(parameters=[msg])
            result = self._call(client, req, timeout).results[0]
        finally:
            self.node.destroy_client(client)
        return bool(result.successful), str(result.reason)

    # ------------------------------------------------------------------------ lease
    def _token(self) -> int:
        """The lease token for a command: acquired first when ``lease="auto"`` and the node's
        lease is on (0 when there is none to have)."""
        with self._lease_lock:
            if self.lease_token or self._lease_mode != "auto":
                return self.lease_token
            if self.lease_enabled is None:
                try:
                    self.lease_enabled = self.lease_status(timeout=5.0).enabled
                except ClientError:
                    return 0  # no lease service (yet): ask again with the next command
            if self.lease_enabled:
                self.acquire_lease()
            return self.lease_token

    def lease_status(self, timeout: float = 5.0) -> Any:
        """The node's ``lease`` status answer (``Lease.Response``)."""
        return self._lease_call("status", timeout=timeout)

    def acquire_lease(
        self, takeover: bool = False, ttl_s: float | None = None, timeout: float = 5.0
    ) -> tuple[bool, str]:
        """Acquire the node's control lease (``takeover``: from whoever holds it; ``ttl_s``:
        its time to live, default the client's or the node's) and keep it alive until
        :meth:`release_lease` or ``close``. Registers this client's command publishers as the
        holder's."""
        if ttl_s is not None:
            self._lease_ttl_s = float(ttl_s)
        resp = self._lease_call("takeover" if takeover else "acquire", timeout=timeout)
        with self._lease_lock:
            self.lease_enabled = bool(resp.enabled)
            if resp.success and resp.token:
                self.lease_token = int(resp.token)
                self._lease_ttl_granted = float(resp.ttl_s)
                self.lease_lost = ""
                self._start_keeper()
        return bool(resp.success), str(resp.message)

    def release_lease(self, timeout: float = 5.0) -> tuple[bool, str]:
        """Give the lease back: a deliberate hand-back, the outputs stay as they are."""
        with self._lease_lock:
            token, self.lease_token = self.lease_token, 0
        if not token:
            return False, "this client holds no lease"
        resp = self._lease_call("release", token=token, timeout=timeout)
        return bool(resp.success), str(resp.message)

    def _lease_call(self, operation: str, token: int = 0, timeout: float = 5.0) -> Any:
        req = Lease.Request(
            operation=operation,
            holder=self.node.get_fully_qualified_name(),
            ttl_s=self._lease_ttl_s,
            token=token,
        )
        if operation in ("acquire", "takeover", "renew"):
            topics = [f"{self.prefix}{t}" for t in COMMAND_TOPICS]
            # Its command publishers, and its action clients (a FollowJointTrajectory goal is
            # known by the client's goal-reply reader; the keeper's renewals pick up clients
            # made after the lease was granted).
            gids = own_publisher_gids(self.node, topics) + own_goal_reply_gids(self.node)
            req.gids = list(gids)
            # Its own node too: a publisher or action client it makes later is found in the
            # graph (the node looks again before refusing one).
            own = self.node.get_fully_qualified_name()
            req.writer_nodes = list(dict.fromkeys([own, *self.lease_writers]))
        return self._call(self._lease_client, req, timeout)

    def _start_keeper(self) -> None:
        if self._keeper is not None and self._keeper.is_alive():
            return
        self._keeper_stop.clear()
        self._keeper = threading.Thread(target=self._keep, name="ether_ros-lease", daemon=True)
        self._keeper.start()

    def _keep(self) -> None:
        """Renew the lease a few times per time to live; stop when it is lost."""
        while True:
            period = min(max(self._lease_ttl_granted / 4, 0.05), 1.0)
            if self._keeper_stop.wait(period):
                return
            with self._lease_lock:
                token = self.lease_token
            if not token:
                return
            try:
                resp = self._lease_call("renew", token=token, timeout=max(period, 1.0))
            except ClientError as exc:
                self.lease_lost = f"renewing the lease: {exc}"
                continue  # keep trying while the lease may still run
            if not resp.success:
                with self._lease_lock:
                    if self.lease_token == token:
                        self.lease_token = 0
                    self.lease_lost = str(resp.message)
                return

    def wait_for_node(self, timeout: float = 20.0) -> str:
        """Wait until the node answers ``get_state``; returns its lifecycle state."""
        deadline = time.monotonic() + timeout
        while True:
            try:
                return self.get_state(timeout=max(0.5, min(2.0, deadline - time.monotonic())))
            except ClientError:
                if time.monotonic() >= deadline:
                    raise


def _axis_answer(resp: Any) -> tuple[bool, str, dict[str, str]]:
    states = dict(zip(resp.joints, resp.states, strict=True))
    return bool(resp.success), str(resp.message), states


def make_write(slave: str | int, variable: str, value: float | str) -> WriteVariable:
    msg = WriteVariable()
    if isinstance(slave, int):
        msg.position = slave
    elif slave.lower() == "all":
        msg.all_slaves = True
    else:
        msg.slave = slave
    msg.variable = variable
    if isinstance(value, str):
        msg.text = value
    else:
        msg.value = float(value)
    return msg


_counter = itertools.count()


def _unique() -> str:
    import os

    return f"{os.getpid()}_{next(_counter)}"
