"""The ``ether_ros`` ROS 2 lifecycle node (default name ``ether_comm``, from ``ros.node_name``).

Lifecycle (managed node; transitions through ``~/change_state`` or the ``ethercat_communicator``
service):

- configure: load the configuration file and open the bus (scan, check against the config);
  publish the process-data layout on ``bus_layout`` (transient local);
- activate: bring the bus to OP and start the cyclic exchange; start publishing;
- deactivate: stop publishing; safe outputs on the wire, slaves to SAFEOP (the master then takes
  them on to INIT) and the cyclic exchange stops;
- cleanup / shutdown: close the bus and release the interface.

Topics, services and parameters are listed in docs/ros.md, next to the thesis's Table 4.3.

Threads: the ROS executors and the sample publisher thread
(:mod:`ether_ros.ros.sample_publisher`) are plain Python threads; the engine's real-time thread
never waits for any of them. ``pdo_listener`` is served by a native thread
(:mod:`ether_ros.ros.native_commands`) that writes valid requests into the engine without
Python and hands the rest to ``_on_write_topic``. With ``command_node=True`` (``ether-ros run``)
the other command services (write_variables, panic) have a node and an executor thread of their
own (see ``spin``); otherwise panic has its own callback group. Either way they are served even
while a transition or an SDO transfer is in progress.
"""

from __future__ import annotations

import contextlib
import functools
import json
import logging
import os
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import rclpy
import rclpy.executors
from diagnostic_msgs.msg import DiagnosticArray
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
from rcl_interfaces.msg import ParameterDescriptor, SetParametersResult
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup, ReentrantCallbackGroup
from rclpy.executors import ExternalShutdownException
from rclpy.lifecycle import LifecycleNode, LifecycleState, TransitionCallbackReturn
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import (
    DurabilityPolicy,
    HistoryPolicy,
    QoSProfile,
    ReliabilityPolicy,
    qos_profile_sensor_data,
)
from sensor_msgs.msg import JointState
from std_srvs.srv import Trigger
from trajectory_msgs.msg import JointTrajectory

from ether_ros._native.protocol import format_address
from ether_ros.config import types as dt
from ether_ros.config.bus import MAX_DECIMATION, MAX_ROS_PERIOD_MS, check_node_name
from ether_ros.errors import EtherRosError
from ether_ros.ros import bridge, command_watchdog, diagnostics, error_fields, joints, security
from ether_ros.ros.convert import layout_msg
from ether_ros.ros.follow_joint_trajectory import PERIOD_S, FollowJointTrajectoryServer
from ether_ros.ros.layout import BusSpec, LayoutError
from ether_ros.ros.lease import (
    ControlLease,
    LeaseRefused,
    goal_reply_topic,
    graph_writer_gids,
)
from ether_ros.ros.native_commands import (
    CommandPathError,
    NativeCommandPath,
    RefusalBudget,
    checked_message,
    housekeeping_cpus,
)
from ether_ros.ros.sample_publisher import Rates, SamplePublisher
from ether_ros.ros.values import InvalidValue, data_type, to_python

log = logging.getLogger(__name__)

#: The joint topics (relative names: under the node's namespace). External configurations name
#: them too (config/topic_based_ros2_control/, tests/unit/test_topic_based_ros2_control.py).
JOINT_STATES_TOPIC = "joint_states"
JOINT_COMMANDS_TOPIC = "joint_commands"

# QoS per stream. High-rate process data: best effort, a deep queue so a burst is not lost in
# the middleware (subscribers must be best effort too, e.g. qos_profile_sensor_data).
QOS_HIGH_RATE = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=100,
    reliability=ReliabilityPolicy.BEST_EFFORT,
    durability=DurabilityPolicy.VOLATILE,
)
QOS_SENSOR = qos_profile_sensor_data
QOS_RELIABLE = QoSProfile(
    history=HistoryPolicy.KEEP_LAST, depth=10, reliability=ReliabilityPolicy.RELIABLE
)
QOS_COMMANDS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST, depth=100, reliability=ReliabilityPolicy.RELIABLE
)
# The answers on write_results/joint_results: every client's answers share each topic, so a
# client's reader must hold more than the others' refusals that arrive while it is busy. The
# refusals are bounded (crates/commands/src/receiver.rs: REFUSAL_ANSWERS_PER_S per publisher,
# REFUSAL_ANSWERS_TOTAL_PER_S per topic): 1000 answers are 20 s of the worst flood's refusals,
# where 100 were 2.5 s, which a client stalled on a loaded host overran and lost its own answer.
QOS_RESULTS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST, depth=1000, reliability=ReliabilityPolicy.RELIABLE
)
QOS_LATCHED = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=1,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.TRANSIENT_LOCAL,
)

# Parameters the operator may change at run time, with their bounds (inclusive); every other
# ``bus.*``/``slaves.*``/``ros.*``/``axes.*`` parameter mirrors the configuration file and is
# read-only (edit the file, then reconfigure). The bounds are the configuration file's
# (config/bus.py): a period in ns must fit the int64 rcl keeps a timer's period in. docs/ros.md
# lists them.
_RUNTIME_PARAMETERS: dict[str, tuple[int, int]] = {
    "ros.raw_decimation": (1, MAX_DECIMATION),
    "ros.decoded_decimation": (1, MAX_DECIMATION),
    "ros.snapshot_period_ms": (0, MAX_ROS_PERIOD_MS),
    "command_timeout_ms": (0, 60_000),
    "diagnostics_period_ms": (1, MAX_ROS_PERIOD_MS),
    "diagnostics_window_ms": (1, MAX_ROS_PERIOD_MS),
}
# ``interface`` may change at run time too: it is a string, used at the next configure.
_INTERFACE_PARAMETER = "interface"
# Longest network interface name Linux takes (IFNAMSIZ - 1).
_MAX_INTERFACE_NAME = 15

BusOpener = Callable[..., Any]

# Nice value of the command executor's thread (see ``spin``).
COMMAND_THREAD_NICE = -10

# The topics that command the bus: a lease holder's publishers on these are the holder's.
COMMAND_TOPICS = ("pdo_listener", "joint_commands", "joint_trajectory")
# Lifecycle transitions the ``ethercat_communicator`` service runs by name (with the lease).
#: How often the node looks for axes that cannot move, to answer their joint commands itself.
AXIS_WATCH_PERIOD_S = 0.02
#: ``ethercat_communicator``'s parameter write with the lease: ``set_parameter NAME VALUE``.
SET_PARAMETER_COMMAND = "set_parameter"
_TRANSITIONS = ("configure", "activate", "deactivate", "cleanup", "shutdown")


def _open_bus(config: Any, interface: str | None = None, link: Any = None) -> Any:
    from ether_ros.master.bus import Bus

    return Bus.open(config, interface=interface, link=link)


def load_config(path: str, interface: str | None, link: str | None = None) -> Any:
    from ether_ros.config import load_bus_config

    return load_bus_config(path, interface=interface or None, link=link)


#: The answer to clear_panic: clearing a stop does not restart anything (ISO 13850).
CLEARED_MESSAGE = (
    "panic cleared: outputs stay at their safe values until you command them again "
    "(CiA 402 axes follow their restart rule: by default they wait for an explicit enable)"
)


class EtherRosNode(LifecycleNode):
    """The lifecycle node on one bus configuration (see the module doc and docs/ros.md).

    ``link`` (an in-process ``SimNetwork``) replaces the network interface; ``bus_opener`` opens
    the bus (``Bus.open`` by default)."""

    def __init__(
        self,
        config_path: str | Path,
        interface: str | None = None,
        *,
        link: Any = None,
        bus_opener: BusOpener = _open_bus,
        node_name: str | None = None,
        context: Any = None,
        command_node: bool = False,
        native_commands: bool = True,
        link_kind: str | None = None,
    ) -> None:
        # ``link_kind`` overrides bus.link (packet, xdp, auto) each time the bus opens.
        self._link_kind = link_kind
        cfg = load_config(str(config_path), interface, link_kind)
        # A name given outside the file is checked as ros.node_name is (rclpy would raise).
        name = check_node_name(node_name) if node_name is not None else cfg.ros.node_name
        super().__init__(name, namespace=cfg.ros.namespace or None, context=context)
        # The command path (``pdo_listener``, ``write_variables``, ``panic``) optionally lives on
        # a second, plain node ``<name>_commands`` in the same namespace, so the topic and
        # service names do not change; ``spin`` serves it with a single-threaded executor in
        # a thread of its own, which takes a command to the bus several times faster than the
        # multi-threaded executor that rebuilds its wait set in Python for every message.
        self.command_node: Node | None = None
        if command_node:
            self.command_node = rclpy.create_node(
                f"{name}_commands",
                namespace=cfg.ros.namespace or None,
                context=context,
                start_parameter_services=False,
            )
        self._config_path = str(Path(config_path).resolve())
        self._link = link
        self._bus_opener = bus_opener
        self._cfg: Any = cfg
        self._bus: Any = None
        self._spec: BusSpec | None = None
        self._samples: SamplePublisher | None = None
        self._rates = Rates(cfg.ros.raw_decimation, cfg.ros.decoded_decimation)
        self._bus_lock = threading.RLock()
        self._panic = False
        self._last_command = time.monotonic()
        # An output variable was written since the node went active (command_watchdog).
        self._variables_written = False
        # The last command before the node stopped feeding the watchdog (None: feeding).
        self._starved_since: float | None = None
        self._last_error = ""
        self._last_failure: BaseException | None = None  # its error, for the answer's code
        self._mirroring = False

        # Set while the holder's lease-carrying write runs (set_parameters_with_lease): the
        # standard parameter services cannot tell who calls them, so with the lease on they
        # refuse every write (docs/security.md).
        self._lease_write = threading.local()
        self._lease: Any = None
        self._declare_parameters(cfg, interface)
        self.add_on_set_parameters_callback(self._on_set_parameters)

        # The control lease (ether_ros.ros.lease): the gate every command entry point checks.
        lease_cfg = cfg.ros.lease
        self._lease = ControlLease(
            lease_cfg.enabled,
            lease_cfg.ttl_s,
            lease_cfg.max_ttl_s,
            stop_motion=self._stop_motion,
            lookup_writers=graph_writer_gids(
                self, COMMAND_TOPICS, self._goal_reply_topics(cfg.ros.trajectory_action)
            ),
        )
        # Refusals of topic requests Python answers, budgeted per publisher as the native
        # threads budget theirs.
        self._refusal_budget = RefusalBudget()
        # What protects the node (lease, discovery range, DDS profile, DDS security): found once,
        # logged now and reported in the diagnostics.
        self._security = security.detect(self._lease.enabled)
        for line in security.describe(self._security):
            self.get_logger().info(f"security: {line}")
        for warning in self._security.warnings:
            self.get_logger().warning(f"security: {warning}")

        # Callback groups: the default (mutually exclusive) group serializes the lifecycle
        # services, commands, SDO and parameters (what opens, closes or talks acyclically to the
        # bus); writes have their own group, the timers (diagnostics, snapshot) theirs; panic is
        # reentrant and never waits for anything.
        self._writes_group = MutuallyExclusiveCallbackGroup()
        self._timer_group = MutuallyExclusiveCallbackGroup()
        self._panic_group = ReentrantCallbackGroup()
        # The axis services wait for the drives (an enable takes up to seconds): a group of
        # their own, served by another thread of the multi-threaded executor, so they hold up
        # neither the lifecycle nor the commands (which never wait on them).
        self._axis_group = MutuallyExclusiveCallbackGroup()
        # CiA 402 axes by joint name while the node is active (bridge.bus_axes).
        self._axes: dict[str, Any] = {}
        # The last joint_trajectory handed to the engine, watched until it ends (None: none).
        self._topic_trajectory: joints.TrajectoryWatch | None = None
        self._topic_lock = threading.Lock()

        self._pub: dict[str, Any] = {
            "pdo_raw": self.create_publisher(PdoRaw, "pdo_raw", QOS_HIGH_RATE),
            "pdo_in": self.create_publisher(SlaveValues, "pdo_in", QOS_SENSOR),
            "pdo_out": self.create_publisher(SlaveValues, "pdo_out", QOS_SENSOR),
            "pdo_out_timer": self.create_publisher(SlaveValues, "pdo_out_timer", QOS_RELIABLE),
            "joint_states": self.create_publisher(JointState, JOINT_STATES_TOPIC, QOS_RELIABLE),
            "joint_extras": self.create_publisher(JointExtras, "joint_extras", QOS_RELIABLE),
        }
        self._layout_pub = self.create_publisher(BusLayout, "bus_layout", QOS_LATCHED)
        self._diag_pub = self.create_publisher(DiagnosticArray, "diagnostics", QOS_RELIABLE)
        self._result_pub = self.create_publisher(WriteResult, "write_results", QOS_RESULTS)
        # Refused joint_commands and every joint_trajectory's answer (request_id 0).
        self._joint_result_pub = self.create_publisher(WriteResult, "joint_results", QOS_RESULTS)

        commands: Node = self.command_node or self
        # pdo_listener: the native path (see ether_ros.ros.native_commands); the Python
        # subscription only if it cannot start (or native_commands=False, for comparison).
        # joint_commands likewise, on a native thread of its own.
        self._native: NativeCommandPath | None = None
        self._native_joints: NativeCommandPath | None = None
        self._native_trajectory: NativeCommandPath | None = None
        if native_commands:
            self._native = self._native_path(
                cfg, "pdo_listener", WriteVariable, self._result_pub, self._on_write_topic
            )
            self._native_joints = self._native_path(
                cfg,
                JOINT_COMMANDS_TOPIC,
                JointState,
                self._joint_result_pub,
                self._on_joint_commands,
            )
            # joint_trajectory: every message goes to Python, but taken natively so it is
            # checked against the lease by its publisher and queued fairly per publisher.
            self._native_trajectory = self._native_path(
                cfg,
                "joint_trajectory",
                JointTrajectory,
                self._joint_result_pub,
                self._on_joint_trajectory,
                kind="passthrough",
            )
        # The Python subscriptions take the serialized message and check it before rclpy
        # turns it into Python (which would cut a name at a NUL): see _checked.
        if self._native is None:
            commands.create_subscription(
                WriteVariable,
                "pdo_listener",
                self._checked(WriteVariable, "pdo_listener", self._on_write_topic),
                QOS_COMMANDS,
                callback_group=None if self.command_node else self._writes_group,
                raw=True,
            )
        if self._native_joints is None:
            commands.create_subscription(
                JointState,
                JOINT_COMMANDS_TOPIC,
                self._checked(JointState, JOINT_COMMANDS_TOPIC, self._on_joint_commands),
                QOS_COMMANDS,
                callback_group=None if self.command_node else self._writes_group,
                raw=True,
            )
        commands.create_service(
            WriteVariables,
            "write_variables",
            self._on_write_service,
            callback_group=None if self.command_node else self._writes_group,
        )
        commands.create_service(
            Trigger,
            "panic",
            self._on_panic,
            callback_group=None if self.command_node else self._panic_group,
        )
        if self._native_trajectory is None:
            commands.create_subscription(
                JointTrajectory,
                "joint_trajectory",
                self._checked(JointTrajectory, "joint_trajectory", self._on_joint_trajectory),
                QOS_COMMANDS,
                callback_group=None if self.command_node else self._writes_group,
                raw=True,
            )
        # The lease service answers beside panic: it never waits for the bus.
        commands.create_service(
            Lease,
            "lease",
            self._on_lease,
            callback_group=None if self.command_node else self._panic_group,
        )
        for service in bridge.AXIS_SERVICES:
            self.create_service(
                AxisCommand,
                service,
                functools.partial(self._on_axis_service, service),
                callback_group=self._axis_group,
            )
        self.create_service(SetMode, "set_mode", self._on_set_mode, callback_group=self._axis_group)
        # A write of outputs that never waits: served like write_variables.
        commands.create_service(
            SetExtras,
            "set_extras",
            self._on_set_extras,
            callback_group=None if self.command_node else self._writes_group,
        )
        self._trajectory_action = self._serve_trajectory_action(cfg)
        # A joint_trajectory that cannot end (a joint left its mode, was disabled, stopped) is
        # reported on joint_results within a period of the node seeing it, by a thread of its
        # own that sleeps while no trajectory runs: no executor timer (100 Hz of executor
        # rounds cost every other callback), and a long diagnostics round never delays it.
        self._topic_watch_wake = threading.Event()
        self._topic_watch_stop = False
        self._topic_watcher = threading.Thread(
            target=self._topic_watch_loop, name="ether_ros-traj-watch", daemon=True
        )
        self._topic_watcher.start()
        # Joint commands for an axis that cannot move (in fault, restart blocked, disabled, the
        # bus in panic) are refused, saying why, instead of being written to an axis that will
        # not follow them: on the native path by the receiver itself, from the state the RT
        # thread published last cycle (crates/commands, `JointTable::blocked`); in Python by
        # `_refuse_blocked`. A thread of its own looks at the axes every AXIS_WATCH_PERIOD_S to
        # note what stopped each one (`_stop_cause`), which both name in their answers.
        self._hold_lock = threading.Lock()
        self._held_mode: set[str] = set()
        self._held_blocked: frozenset[str] = frozenset()
        self._causes_sent: dict[str, str] = {}
        # What stopped an axis it did not ask to stop, by joint (``_note_stop_cause``).
        self._stop_cause: dict[str, str] = {}
        self._axis_watch_stop = threading.Event()
        self._axis_watcher = threading.Thread(
            target=self._axis_watch_loop, name="ether_ros-axis-watch", daemon=True
        )
        self._axis_watcher.start()
        self.create_service(Command, "ethercat_communicator", self._on_command)
        self.create_service(SdoRead, "sdo_read", self._on_sdo_read)
        self.create_service(SdoWrite, "sdo_write", self._on_sdo_write)

        self._windows = diagnostics.Windows(self._param_ms("diagnostics_window_ms") / 1000.0)
        self._diag_timer = self.create_timer(
            self._param_ms("diagnostics_period_ms") / 1000.0,
            self._publish_diagnostics,
            callback_group=self._timer_group,
        )
        self._snapshot_timer: Any = None
        # With the lease on, the lifecycle's own change_state (lifecycle_msgs, no lease field)
        # is refused: transitions go through ethercat_communicator with the holder's token.
        change_state = getattr(self, "_service_change_state", None)
        if change_state is not None and self._lease.enabled:
            change_state.callback = self._refuse_change_state
        self._lease.start()

    # ------------------------------------------------------------------------ parameters
    def _declare_parameters(self, cfg: Any, interface: str | None) -> None:
        self.declare_parameter(
            "config",
            self._config_path,
            ParameterDescriptor(description="bus configuration file", read_only=True),
        )
        self.declare_parameter(
            "interface",
            interface or "",
            ParameterDescriptor(description="network interface (empty: bus.interface)"),
        )
        self.declare_parameter(
            "command_timeout_ms",
            0,
            ParameterDescriptor(
                description="no write for this long -> the engine's watchdog puts the safe "
                "outputs on the wire until the next write (0: off)"
            ),
        )
        self.declare_parameter(
            "diagnostics_period_ms", 1000, ParameterDescriptor(description="diagnostics period")
        )
        self.declare_parameter(
            "diagnostics_window_ms",
            10000,
            ParameterDescriptor(
                description="the diagnostics' levels come from rates over this window"
            ),
        )
        for name, value in config_parameters(cfg).items():
            self.declare_parameter(
                name,
                value,
                ParameterDescriptor(
                    description="from the configuration file",
                    dynamic_typing=True,
                ),
            )

    def _update_mirror(self, cfg: Any) -> None:
        params = []
        self._mirroring = True
        try:
            for name, value in config_parameters(cfg).items():
                if self.has_parameter(name):
                    params.append(Parameter(name, value=value))
                else:
                    self.declare_parameter(name, value, ParameterDescriptor(dynamic_typing=True))
            self.set_parameters(params)
        finally:
            self._mirroring = False

    def _on_set_parameters(self, params: list[Parameter]) -> SetParametersResult:
        """Every parameter write passes here before it takes effect (the standard parameter
        services and ``set_parameters_with_lease`` alike): with the control lease on, only the
        holder's lease-carrying write passes; every value is checked (type, range, whether it
        may change at run time) so that nothing invalid reaches a timer or the engine."""
        if self._mirroring:
            return SetParametersResult(successful=True)
        if (
            self._lease is not None
            and self._lease.enabled
            and not getattr(self._lease_write, "active", False)
        ):
            holder = self._lease.holder()
            return SetParametersResult(
                successful=False,
                reason="the control lease is on"
                + (f" (held by '{holder}')" if holder else " (nobody holds it)")
                + ": parameters change only through ethercat_communicator "
                "'set_parameter NAME VALUE' with the lease token (reading stays free)",
            )
        for p in params:
            reason = self._check_parameter(p)
            if reason:
                return SetParametersResult(successful=False, reason=reason)
        for p in params:
            if p.name == "ros.raw_decimation":
                self._rates.raw_decimation = int(p.value)
            elif p.name == "ros.decoded_decimation":
                self._rates.decoded_decimation = int(p.value)
            elif p.name == "ros.snapshot_period_ms":
                self._restart_snapshot_timer(int(p.value))
            elif p.name == "diagnostics_period_ms":
                self._diag_timer.timer_period_ns = int(p.value) * 1_000_000
                self._diag_timer.reset()
            elif p.name == "diagnostics_window_ms":
                self._windows = diagnostics.Windows(int(p.value) / 1000.0)
        return SetParametersResult(successful=True)

    def _check_parameter(self, p: Parameter) -> str:
        """Why the value of ``p`` may not take effect ("" when it may)."""
        if p.name == _INTERFACE_PARAMETER:
            value = p.value
            if not isinstance(value, str):
                return f"{p.name} is a string (a network interface name, empty: bus.interface)"
            if len(value) > _MAX_INTERFACE_NAME or any(c in value for c in "/ \t\n\0:"):
                return (
                    f"{p.name} '{value[:40]}' is not a network interface name "
                    f"(at most {_MAX_INTERFACE_NAME} characters, no '/', ':' or blanks)"
                )
            return ""
        bounds = _RUNTIME_PARAMETERS.get(p.name)
        if bounds is None:
            if self.has_parameter(p.name):
                return (
                    f"{p.name} mirrors the configuration file and does not change at run time; "
                    "edit the file and reconfigure the node"
                )
            return f"{p.name} is not a parameter of this node"
        if not isinstance(p.value, int) or isinstance(p.value, bool):
            return f"{p.name} is an integer (got {type(p.value).__name__} {p.value!r:.40})"
        low, high = bounds
        if p.name == "command_timeout_ms" and p.value:
            # A timeout shorter than two cycles trips between two commands sent every cycle.
            low = max(1, -(-2 * int(self._cfg.bus.cycle_us) // 1000))
            if p.value < low:
                return f"{p.name} must be 0 (off) or at least {low} (two bus cycles)"
        if not low <= p.value <= high:
            return f"{p.name} must be within {low}..{high} (got {p.value})"
        return ""

    def set_parameters_with_lease(self, name: str, value: Any) -> tuple[bool, str]:
        """The holder's way to change a parameter while the lease is on (the caller has checked
        the token): the same checks as the standard services, then the value takes effect."""
        try:
            param = Parameter(name, value=value)
        except (TypeError, ValueError) as exc:
            return False, f"{name}: {exc}"
        if not self.has_parameter(name):
            return False, f"{name} is not a parameter of this node"
        self._lease_write.active = True
        try:
            result = self.set_parameters([param])[0]
        except Exception as exc:  # rclpy refuses a type change of a declared parameter
            return False, f"{name}: {exc}"
        finally:
            self._lease_write.active = False
        if not result.successful:
            reason = str(result.reason)  # rclpy's own type check does not name the parameter
            return False, reason if name in reason else f"{name}: {reason}"
        return True, f"{name} = {value!r}"

    def _describe_claim(self, bus: Any) -> None:
        """Name this node in the bus's interface claim (a second master is refused naming
        it), and let other processes' writes through the claim (the inspection tools'
        ``download``) pass only while the control lease is off: with the lease on, writes go
        through this node's services with the holder's token."""
        claim = getattr(bus, "claim", None)
        if claim is not None:
            claim.info["node"] = self.get_fully_qualified_name()
        lease = self._lease

        def refusal() -> str | None:
            if not lease.enabled:
                return None
            holder = lease.holder()
            return (
                "the control lease is on"
                + (f" (held by {holder})" if holder else "")
                + ": write through the node's sdo service with the lease token"
            )

        if hasattr(bus, "remote_write_refusal"):
            bus.remote_write_refusal = refusal

    def _param_ms(self, name: str) -> int:
        return int(self.get_parameter(name).value)

    # ------------------------------------------------------------------------ lifecycle
    def on_configure(self, state: LifecycleState) -> TransitionCallbackReturn:
        interface = str(self.get_parameter("interface").value) or None
        try:
            cfg = load_config(self._config_path, interface, self._link_kind)
            with self._bus_lock:
                bus = self._bus_opener(cfg, interface=interface, link=self._link)
                self._cfg, self._bus = cfg, bus
                self._spec = bridge.bus_spec(bus)
                self._describe_claim(bus)
            self._update_mirror(cfg)
            self._rates.raw_decimation = self._param_ms("ros.raw_decimation")
            self._rates.decoded_decimation = self._param_ms("ros.decoded_decimation")
        except EtherRosError as exc:
            return self._fail("configure", exc)
        self._layout_pub.publish(self._layout_message())
        self.get_logger().info(
            f"configured: {len(self._spec.slaves)} slave(s) on {cfg.bus.interface}"
        )
        self._last_error = ""
        return TransitionCallbackReturn.SUCCESS

    def on_activate(self, state: LifecycleState) -> TransitionCallbackReturn:
        bus, spec = self._bus, self._spec
        if bus is None or spec is None:
            return self._fail("activate", EtherRosError("the bus is not open"))
        try:
            with self._bus_lock:
                bus.start()
                self._axes = bridge.bus_axes(bus)
                if self._native is not None:
                    self._native.attach(bus, spec)
                if self._native_joints is not None and self._axes:
                    self._native_joints.attach_joints(bus, self._axes)
                    # The axes start disabled: their commands are Python's until enabled.
                    self._held_blocked = self._blocked_axes()
                    self._apply_holds()
        except EtherRosError as exc:
            self._stop_bus()
            return self._fail("activate", exc)
        self._panic = False
        self._last_command = time.monotonic()
        self._windows = diagnostics.Windows(self._param_ms("diagnostics_window_ms") / 1000.0)
        self._variables_written = False
        # Half a second of samples at most per batch: beyond that ROS has fallen behind and
        # the oldest samples are skipped (and counted) rather than published late.
        backlog = max(100, int(0.5e6 / max(spec.cycle_us, 1)))
        self._samples = SamplePublisher(
            bus,
            spec,
            self._pub,
            self._cfg.joint_specs(),
            self._rates,
            self._feed_watchdog,
            max_backlog=backlog,
            axis_joints=(
                joints.AxisImageJoints(
                    [e for e in bridge.axis_plan_entries(bus) if e.name in self._axes]
                )
                if self._axes
                else None
            ),
            axis_slaves={name: axis.spec.slave for name, axis in self._axes.items()},
            feeder_priority=command_priority(self._cfg),
            axis_extras=(
                (lambda: joints.axis_extra_values(self._axes))
                if joints.has_extras(self._axes)
                else None
            ),
            axis_states=self._axis_states if self._axes else None,
        )
        self._samples.start()
        self._restart_snapshot_timer(self._param_ms("ros.snapshot_period_ms"))
        self.get_logger().info("active: cyclic exchange running, slaves in OP")
        self._last_error = ""
        return TransitionCallbackReturn.SUCCESS

    def on_deactivate(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._stop_publishing()
        self._stop_bus()
        self.get_logger().info("inactive: safe outputs sent, cyclic exchange stopped")
        return TransitionCallbackReturn.SUCCESS

    def on_cleanup(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._release()
        return TransitionCallbackReturn.SUCCESS

    def on_shutdown(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._release()
        return TransitionCallbackReturn.SUCCESS

    def on_error(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._release()
        return TransitionCallbackReturn.SUCCESS

    def _fail(self, what: str, exc: BaseException) -> TransitionCallbackReturn:
        self._last_error = f"{what} failed: {exc}"
        self._last_failure = exc
        self.get_logger().error(self._last_error)
        if what == "configure":
            self._release()
        return TransitionCallbackReturn.FAILURE

    def _stop_publishing(self) -> None:
        if self._snapshot_timer is not None:
            self._snapshot_timer.cancel()
            self.destroy_timer(self._snapshot_timer)
            self._snapshot_timer = None
        if self._samples is not None:
            self._samples.stop()
            self._samples = None

    def _stop_bus(self) -> None:
        for native in self._native_paths():
            native.detach()  # before the bus stops: no native write after this
        with self._bus_lock:
            self._axes = {}
            if self._bus is not None:
                try:
                    self._bus.stop()
                except EtherRosError as exc:
                    self.get_logger().warning(f"stopping the bus: {exc}")

    def _release(self) -> None:
        self._stop_publishing()
        for native in self._native_paths():
            native.detach()
        with self._bus_lock:
            bus, self._bus, self._spec = self._bus, None, None
            self._axes = {}
            if bus is not None:
                try:
                    bus.close()
                except EtherRosError as exc:
                    self.get_logger().warning(f"closing the bus: {exc}")

    def lifecycle_state(self) -> str:
        return str(self._state_machine.current_state[1])

    def destroy_node(self) -> None:
        self._axis_watch_stop.set()
        self._axis_watcher.join(1.0)
        self._topic_watch_stop = True
        self._topic_watch_wake.set()
        self._topic_watcher.join(1.0)
        self._lease.close()
        self._release()
        if self._trajectory_action is not None:
            self._trajectory_action.destroy()
            self._trajectory_action = None
        for native in self._native_paths():
            native.close()
        self._native = self._native_joints = self._native_trajectory = None
        if self.command_node is not None:
            self.command_node.destroy_node()
            self.command_node = None
        super().destroy_node()

    # ------------------------------------------------------------------------ publishing
    def _layout_message(self) -> BusLayout:
        assert self._spec is not None
        msg = layout_msg(self._spec)
        msg.header.stamp = self.get_clock().now().to_msg()
        return msg

    def _restart_snapshot_timer(self, period_ms: int) -> None:
        if self._snapshot_timer is not None:
            self._snapshot_timer.cancel()
            self.destroy_timer(self._snapshot_timer)
            self._snapshot_timer = None
        if period_ms > 0 and self._samples is not None:
            self._snapshot_timer = self.create_timer(
                period_ms / 1000.0, self._publish_snapshot, callback_group=self._timer_group
            )

    def _publish_snapshot(self) -> None:
        """``pdo_out_timer``: the commanded outputs of every slave, periodically (as the
        thesis's /pdo_out_timer), whether or not anything changed."""
        with self._bus_lock:
            bus, spec = self._bus, self._spec
            if bus is None or spec is None or self._samples is None:
                return
            stamp = self.get_clock().now().to_msg()
            for s in spec.slaves:
                if not s.outputs:
                    continue
                values = bus.outputs(s.name)
                msg = SlaveValues()
                msg.header.stamp = stamp
                msg.header.frame_id = s.name
                msg.slave = s.name
                msg.position = s.position
                msg.cycle = self._samples.counters.last_cycle
                msg.values = [float(values[v.name]) for v in s.outputs]
                self._pub["pdo_out_timer"].publish(msg)

    def _publish_diagnostics(self) -> None:
        name = self.get_fully_qualified_name()
        lifecycle = self.lifecycle_state()
        raw: dict[str, Any] = {}
        statuses = []
        ros_numbers: dict[str, float] = {}
        dc_error = 0.0
        bus, spec = self._bus, self._spec
        running = bus is not None and getattr(bus, "running", False)
        if running:
            try:
                raw = dict(bus.stats())
            except EtherRosError as exc:
                self.get_logger().warning(f"reading statistics: {exc}")
        stats = bridge.flat_stats(raw)
        frames = list(raw.get("frames") or [])
        stats["frames_sent"] = float(sum(int(f.get("sent", 0)) for f in frames))
        cycle_ns = int(spec.cycle_us) * 1000 if spec is not None else 0
        now_ns = time.clock_gettime_ns(time.CLOCK_MONOTONIC)
        stale = diagnostics.stale_frames(frames, cycle_ns, now_ns) if running else []
        ages = diagnostics.frame_ages(frames, cycle_ns, now_ns) if running else []
        samples = self._samples
        if samples is not None:
            c = samples.counters
            ros_numbers = {
                "samples": c.samples,
                "published_raw": c.published_raw,
                "published_decoded": c.published_decoded,
                "dropped": c.dropped,
                "watchdog_cycles": c.watchdog_cycles,
                "watchdog_active": float(bool(c.last_flags & bridge.FLAG_WATCHDOG)),
                "panic_cycles": c.panic_cycles,
                "last_cycle": c.last_cycle,
                "working_counter": c.wkc,
                "stale_samples": c.stale_samples,
            }
            dc_error = samples.take_dc_error()
            commands = self.command_path_counters()
            if commands:
                ros_numbers["commands_native"] = commands["applied"]
                ros_numbers["commands_deferred"] = commands["deferred"]
                ros_numbers["commands_refused_queue_full"] = commands["overflowed"]
                ros_numbers["commands_refused"] = commands["refused"]
                ros_numbers["commands_refused_lease"] = commands["refused_lease"]
                ros_numbers["commands_refused_throttled"] = commands["throttled"]
                ros_numbers["commands_rcl_errors"] = commands["rcl_errors"]
                if commands["delivery_count"]:
                    ros_numbers["command_delivery_mean_ns"] = (
                        commands["delivery_sum_ns"] / commands["delivery_count"]
                    )
                    ros_numbers["command_delivery_max_ns"] = commands["delivery_max_ns"]
            joint_commands = self.joint_command_path_counters()
            if joint_commands:
                ros_numbers["joint_commands_native"] = joint_commands["applied"]
                ros_numbers["joint_commands_deferred"] = joint_commands["deferred"]
                ros_numbers["joint_commands_refused"] = joint_commands["refused"]
                ros_numbers["joint_commands_refused_lease"] = joint_commands["refused_lease"]
                ros_numbers["joint_commands_refused_blocked"] = joint_commands["blocked"]
                ros_numbers["joint_commands_refused_throttled"] = joint_commands["throttled"]
        supervisor = getattr(bus, "supervisor", None)
        problems = supervisor.branch_problems() if supervisor is not None else []
        groups: list[Any] = []
        if running and bus is not None:
            try:
                groups = list(bus.group_stats(raw))
            except Exception as exc:
                self.get_logger().warning(f"reading group statistics: {exc}")
        now = time.monotonic()
        window = self._windows.master.update(
            now, {k: bridge.stat(stats, k) for k in diagnostics.WINDOW_COUNTERS}
        )
        statuses.append(
            diagnostics.master_status(
                name,
                lifecycle,
                stats,
                ros_numbers,
                self._panic,
                dc_error,
                problems,
                window=window,
                stale=stale,
                input_age_s=max(ages, default=0.0),
                short_groups=[g.name for g in groups if g.sent and not g.wkc_ok],
                frame_count=len(frames),
            )
        )
        statuses.extend(diagnostics.group_statuses(name, groups, self._windows.groups, now))
        if bus is not None:
            # Not under _bus_lock: reading the AL states is acyclic traffic (a few cycles) and
            # writes must not wait for it. A bus closed meanwhile just skips this report.
            try:
                statuses.extend(diagnostics.slave_statuses(name, bus.states()))
            except Exception as exc:
                self.get_logger().warning(f"reading slave states: {exc}")
        statuses.extend(
            diagnostics.axis_statuses(
                name, self._axis_reports(), self._panic, dict(self._stop_cause)
            )
        )
        statuses.append(security.status(name, self._security, self._lease.status()))
        self._diag_pub.publish(diagnostics.array(statuses, self.get_clock().now().to_msg()))

    def _axis_states(self) -> list[joints.AxisState]:
        """Every axis's state for ``joint_extras``, as the diagnostics report it."""
        causes = dict(self._stop_cause)
        return [
            joints.axis_state(name, mode, st, self._panic, causes.get(name, ""))
            for name, mode, st in self._axis_reports()
        ]

    def _axis_reports(self) -> list[tuple[str, str, dict[str, Any]]]:
        """(joint, commanded mode, status) of every axis, for the diagnostics."""
        reports = []
        for name, axis in list(self._axes.items()):
            try:
                reports.append((name, bridge.axis_mode(axis), bridge.axis_status(axis)))
            except EtherRosError:
                continue  # the bus stopped meanwhile
        return reports

    def _feed_watchdog(self) -> bool:
        """Called by the sample thread every loop: keep the engine's command watchdog fed while
        commands are fresh (or always, when ``command_timeout_ms`` is 0). If this process stalls
        or the commands stop, the engine puts the safe outputs on the wire by itself."""
        timeout_ms = self._param_ms("command_timeout_ms")
        last = self._last_command_time()
        if timeout_ms and (time.monotonic() - last) * 1000.0 > timeout_ms:
            # Once starved, the watchdog stays tripped until the next command.
            if self._starved_since is not None and last <= self._starved_since:
                return False
            if not self._quiet_is_safe():
                self._starved_since = last
                return False
        self._starved_since = None
        bus = self._bus
        if bus is not None:
            bus.feed_watchdog()
        return True

    def _quiet_is_safe(self) -> bool:
        """Nothing needs a live commander (``command_watchdog.quiet_is_safe``): the CiA 402 axes
        run trajectories or hold still, and no output variable was written."""
        native = self._native.counters().get("applied", 0) if self._native is not None else 0
        statuses = []
        for axis in list(self._axes.values()):
            try:
                statuses.append(bridge.axis_status(axis))
            except EtherRosError:
                return False
        return command_watchdog.quiet_is_safe(statuses, self._variables_written or native > 0)

    def _last_command_time(self) -> float:
        """time.monotonic() of the last write, through Python or the native path."""
        native = max((n.last_command_ns() / 1e9 for n in self._native_paths()), default=0.0)
        return max(self._last_command, native)

    def _native_paths(self) -> list[NativeCommandPath]:
        paths = (self._native, self._native_joints, self._native_trajectory)
        return [n for n in paths if n is not None]

    def _native_path(
        self,
        cfg: Any,
        topic: str,
        message_type: Any,
        results: Any,
        handler: Any,
        kind: str | None = None,
    ) -> NativeCommandPath | None:
        """The native command path for ``topic``, or None (with the reason logged) when it
        cannot start: then Python serves the topic."""
        try:
            return NativeCommandPath(
                self,
                topic,
                QOS_COMMANDS,
                results,
                handler,
                command_priority(cfg),
                housekeeping_cpus(cfg.bus.realtime.cpu),
                message_type=message_type,
                kind=kind,
                lease=self._lease.gate,
                handle_refused=functools.partial(self._refuse_message, topic),
            )
        except CommandPathError as exc:
            self.get_logger().warning(f"{exc}; {topic} is served by Python instead")
            return None

    def _checked(
        self, message_type: Any, topic: str, handler: Callable[[Any], None]
    ) -> Callable[[bytes], None]:
        """A raw subscription's callback: the serialized message checked by the native decoder
        (``native_commands.checked_message``), then handed to ``handler`` or refused."""

        def callback(data: bytes) -> None:
            message, problem = checked_message(data, message_type)
            if problem is None:
                handler(message)
            else:
                self._refuse_message(topic, message, problem)

        return callback

    def _refuse_message(
        self, topic: str, message: Any, problem: str, publisher: bytes | None = None
    ) -> None:
        """Answer a command message refused before it was read (``message`` may be None when
        nothing of it could be read): on ``write_results`` for ``pdo_listener`` (with its
        request_id), else on ``joint_results`` — within the publisher's answer budget, as every
        refusal (a flood of bad messages must not become a flood of answers)."""
        text = f"{topic} refused: {problem}"
        self.get_logger().warning(text, throttle_duration_sec=1.0)
        if not self._refusal_budget.spend(publisher):
            return
        if topic == "pdo_listener":
            request_id = int(message.request_id) if message is not None else 0
            self._result_pub.publish(
                WriteResult(request_id=request_id, success=False, message=text)
            )
        else:
            self._joint_result_pub.publish(WriteResult(success=False, message=text))

    def command_path_counters(self) -> dict[str, int]:
        """The native command path's counters (empty when Python serves pdo_listener)."""
        return self._native.counters() if self._native is not None else {}

    def joint_command_path_counters(self) -> dict[str, int]:
        """The native joint_commands path's counters (empty when Python serves it)."""
        return self._native_joints.counters() if self._native_joints is not None else {}

    # ------------------------------------------------------------------------ writes
    def _write(
        self, requests: list[WriteVariable], failure: list[BaseException] | None = None
    ) -> tuple[bool, str]:
        """Apply ``requests``; a typed error that refused them is appended to ``failure``."""
        # Refused before taking the bus lock when not active, so a write arriving during a
        # transition (which holds the lock for seconds) answers at once and never holds up a
        # panic queued behind it on the command executor.
        if self.lifecycle_state() != "active":
            return False, f"the node is {self.lifecycle_state()}: writes need it active"
        with self._bus_lock:
            bus, spec = self._bus, self._spec
            if bus is None or spec is None or self.lifecycle_state() != "active":
                return False, f"the node is {self.lifecycle_state()}: writes need it active"
            try:
                writes = []
                for r in requests:
                    writes.extend(
                        bridge.resolve_write(
                            spec,
                            r.slave,
                            int(r.position),
                            bool(r.all_slaves),
                            r.variable,
                            float(r.value),
                            r.text,
                        )
                    )
                self._last_command = time.monotonic()
                self._variables_written = True
                bridge.apply_writes(bus, writes)
            except EtherRosError as exc:
                if failure is not None:
                    failure.append(exc)
                return False, str(exc)
        return True, bridge.describe_writes(writes)

    def _on_write_topic(self, msg: WriteVariable, publisher: bytes | None = None) -> None:
        try:
            self._lease.check_publisher(publisher)
            ok, message = self._write([msg])
        except LeaseRefused as exc:
            ok, message = False, str(exc)
        if not ok:
            self._warn_refused("write", message)
            if not self._refusal_budget.spend(publisher):
                return
        self._result_pub.publish(
            WriteResult(request_id=msg.request_id, success=ok, message=message)
        )

    def _on_write_service(
        self, req: WriteVariables.Request, resp: WriteVariables.Response
    ) -> WriteVariables.Response:
        failure: list[BaseException] = []
        try:
            self._lease.check_token(req.lease)
            resp.success, resp.message = self._write(list(req.writes), failure)
        except LeaseRefused as exc:
            resp.success, resp.message = False, str(exc)
            failure.append(exc)
        return error_fields.fill(resp, failure[0] if failure else None)

    # ------------------------------------------------------------------------ joints
    def _axes_if_active(self) -> dict[str, Any]:
        """The axes, or AxisRejected when the node is not active (checked without the bus
        lock, like writes, so a refusal never waits for a transition)."""
        state = self.lifecycle_state()
        if state != "active" or not self._axes:
            why = "joint commands need it active" if state != "active" else "no CiA 402 axes"
            raise bridge.AxisRejected(f"the node is {state}: {why}")
        return self._axes

    def joint_command(self, msg: JointState) -> tuple[bool, str]:
        """A ``joint_commands`` message: every setpoint checked, then all written, or nothing
        (``bridge.resolve_joint_command``)."""
        try:
            self._axes_if_active()
            with self._bus_lock:
                commands = bridge.resolve_joint_command(
                    self._axes_if_active(),
                    list(msg.name),
                    list(msg.position),
                    list(msg.velocity),
                    list(msg.effort),
                )
                self._refuse_blocked([axis for axis, _kind, _value in commands])
                self._last_command = time.monotonic()
                bridge.apply_joint_commands(commands)
        except EtherRosError as exc:
            return False, str(exc)
        return True, bridge.describe_joint_commands(commands)

    def _blocked_axes(self) -> frozenset[str]:
        """The joints that cannot follow a setpoint now (``bridge.axis_blocker``); notes what
        stopped each axis that it did not ask to stop (``_stop_cause``)."""
        out = set()
        for name, axis in list(self._axes.items()):
            try:
                st = bridge.axis_status(axis)
            except EtherRosError:
                continue  # the bus stopped meanwhile
            self._note_stop_cause(name, st)
            if bridge.axis_blocker(st, panic=self._panic, check_mode=False):
                out.add(name)
        return frozenset(out)

    def _note_stop_cause(self, name: str, st: Any) -> None:
        """What stopped the axis, seen while it happens (a halt is the command watchdog's or a
        panic's): the engine voids an axis's enable when the stop ends, after which its status
        says only that it is disabled. Forgotten once it is enabled again or disabled on
        purpose (``axis_command``)."""
        if st["state"] == "operation_enabled" and not st.get("halted"):
            self._stop_cause.pop(name, None)
        elif self._panic:
            self._stop_cause.setdefault(name, "a panic")
        elif st.get("halted"):
            self._stop_cause.setdefault(name, "the command watchdog")

    def _apply_holds(self) -> None:
        """Leave to Python the joint commands of the axes changing mode, and tell the native
        path what stopped each axis (it refuses commands to a blocked axis by itself)."""
        with self._hold_lock:
            native, axes = self._native_joints, self._axes
            if native is not None and axes:
                native.set_held(axes, self._held_mode)
                causes = dict(self._stop_cause)
                native.set_causes(axes, causes)
                self._causes_sent = causes

    def _axis_watch_loop(self) -> None:
        while not self._axis_watch_stop.wait(AXIS_WATCH_PERIOD_S):
            if not self._axes:
                continue
            try:
                blocked = self._blocked_axes()
                if blocked != self._held_blocked or self._stop_cause != self._causes_sent:
                    self._held_blocked = blocked
                    self._apply_holds()
            except Exception as exc:  # the watch must outlive a bad round (a closing bus)
                self.get_logger().warning(f"axis watch: {exc}", throttle_duration_sec=5.0)

    def _refuse_blocked(self, axes: list[Any]) -> None:
        """AxisRejected, saying why, when one of ``axes`` cannot follow a setpoint now (in
        fault, restart blocked, disabled, the bus in panic): the command
        is not executed rather than written to an axis that will not move."""
        for axis in axes:
            # A mode not reached yet is not refused: the node holds joint commands in Python
            # while a mode changes, and they take effect once it is reached.
            st = bridge.axis_status(axis)
            why = bridge.axis_blocker(
                st,
                bridge.axis_mode(axis),
                self._panic,
                check_mode=False,
                cause=self._stop_cause.get(axis.name, ""),
            )
            if why:
                raise bridge.AxisRejected(f"joint {axis.name!r} not executed: {why}", field="name")

    def _on_joint_commands(self, msg: JointState, publisher: bytes | None = None) -> None:
        try:
            self._lease.check_publisher(publisher)
            ok, message = self.joint_command(msg)
        except LeaseRefused as exc:
            ok, message = False, str(exc)
        if not ok:  # applied commands are not answered: they come at the controller's rate
            self._warn_refused("joint_commands", message)
            if not self._refusal_budget.spend(publisher):
                return
            self._joint_result_pub.publish(
                WriteResult(success=False, message=f"joint_commands refused: {message}")
            )

    def joint_trajectory(self, msg: JointTrajectory) -> tuple[bool, str]:
        """Check every joint's trajectory, then hand them to the engine at once, timed from
        ``header.stamp`` (docs/ros.md, "Joints")."""
        try:
            axes = self._axes_if_active()
            with self._bus_lock:
                plan = joints.trajectory_plan(
                    axes,
                    msg,
                    bridge.trajectory_capacity(self._bus),
                    time.time_ns(),
                    bridge.engine_now_ns(axes),
                )
                self._last_command = time.monotonic()
                seq = bridge.follow_plan(plan)
                with self._topic_lock:
                    self._topic_trajectory = joints.TrajectoryWatch(plan, seq)
                self._topic_watch_wake.set()
        except EtherRosError as exc:
            return False, str(exc)
        starts = (plan.start_ns - bridge.engine_now_ns(axes)) * 1e-9
        return True, (
            f"trajectory of {len(msg.points)} point(s) over {plan.tracks[0][1][-1][0]:g} s for "
            f"{', '.join(plan.names)}, starting in {starts:.3f} s"
        )

    def _on_joint_trajectory(self, msg: JointTrajectory, publisher: bytes | None = None) -> None:
        try:
            self._lease.check_publisher(publisher)
            ok, message = self.joint_trajectory(msg)
        except LeaseRefused as exc:
            ok, message = False, str(exc)
        if not ok:
            self._warn_refused("joint_trajectory", message)
            if not self._refusal_budget.spend(publisher):
                return
        text = f"joint_trajectory: {message}" if ok else f"joint_trajectory refused: {message}"
        self._joint_result_pub.publish(WriteResult(success=ok, message=text))

    def _topic_watch_loop(self) -> None:
        """Every PERIOD_S while a joint_trajectory runs (``_watch_topic_trajectory``); asleep
        otherwise."""
        while not self._topic_watch_stop:
            if self._topic_trajectory is None:
                self._topic_watch_wake.wait()
                self._topic_watch_wake.clear()
                continue
            try:
                self._watch_topic_trajectory()
            except Exception as exc:  # the watch must outlive a bad round (a closing bus)
                self.get_logger().warning(f"joint_trajectory watch: {exc}")
            time.sleep(PERIOD_S)

    def _watch_topic_trajectory(self) -> None:
        """The running ``joint_trajectory``: once it cannot end by itself (a joint of it left
        the state it needs; the engine has stopped the others quietly), say why on
        ``joint_results`` and in the log; forget it once it ended or a newer command replaced
        it."""
        watch = self._topic_trajectory
        if watch is None:
            return
        try:
            why = watch.outcome([bridge.axis_status(a) for a in watch.axes])
        except EtherRosError:
            why = joints.TrajectoryWatch.OVER  # the bus stopped: deactivate says so
        if why is not None:
            self._end_topic_trajectory(watch, why)

    def _end_topic_trajectory(self, watch: joints.TrajectoryWatch | None, why: str) -> None:
        """Stop watching ``watch`` (None: whichever runs), reporting ``why`` unless it ended
        well (``TrajectoryWatch.OVER``)."""
        with self._topic_lock:
            watch = watch or self._topic_trajectory
            if watch is None or self._topic_trajectory is not watch:
                return  # a newer trajectory is watched meanwhile
            self._topic_trajectory = None
        if why == joints.TrajectoryWatch.OVER:
            return
        text = f"joint_trajectory aborted: {why} ({', '.join(watch.plan.names)})"
        self.get_logger().warning(text)
        self._joint_result_pub.publish(WriteResult(success=False, message=text))

    def _serve_trajectory_action(self, cfg: Any) -> FollowJointTrajectoryServer | None:
        """The FollowJointTrajectory action server (``ros.trajectory_action``; empty: none), on
        the axes while the node is active (docs/ros.md, "FollowJointTrajectory")."""
        if not cfg.ros.trajectory_action:
            return None
        return FollowJointTrajectoryServer(
            self,
            cfg.ros.trajectory_action,
            cfg.ros,
            axes=self._axes_if_active,
            capacity=lambda: bridge.trajectory_capacity(self._bus),
            note_command=self._note_command,
            gate=self._lease.check_goal_sender,
        )

    def _goal_reply_topics(self, action: str) -> list[str]:
        """The DDS topic on which the action server's clients read goal replies (none without
        a server): a lease holder's action clients are looked up there."""
        if not action:
            return []
        return [goal_reply_topic(f"{self.get_namespace().rstrip('/')}/{action}")]

    def _note_command(self) -> None:
        """A command came (it feeds the command watchdog, see ``_feed_watchdog``)."""
        self._last_command = time.monotonic()

    def axis_command(
        self, command: str, names: list[str], mode: str = ""
    ) -> tuple[bool, str, list[str], list[str]]:
        """enable / disable / reset_fault / home / set_mode on the joints named (empty: all):
        (success, message, joints, their CiA 402 states afterwards). Waits for the drives without
        the bus lock, so writes and other commands go on meanwhile."""
        self._note_command()
        try:
            chosen = bridge.select_axes(self._axes_if_active(), names)
            if command == "set_mode":
                bridge.check_mode(chosen, mode)
        except EtherRosError as exc:
            return False, str(exc), [], []
        if command in ("disable", "enable"):  # a deliberate state: no stop to explain
            for axis in chosen:
                self._stop_cause.pop(axis.name, None)
        changing = command in bridge.MODE_CHANGING
        if changing:  # while the mode changes, Python checks every joint command
            self._held_mode.update(axis.name for axis in chosen)
            self._apply_holds()
        errors = []
        try:
            for axis in chosen:
                try:
                    bridge.run_axis_command(axis, command, mode)
                except EtherRosError as exc:
                    errors.append(str(exc))
        finally:
            if changing:
                self._held_mode.difference_update(axis.name for axis in chosen)
            # After an enable, reset_fault or a mode change, the axes' blockers are seen again.
            self._held_blocked = self._blocked_axes()
            self._apply_holds()
        states = []
        for axis in chosen:
            try:
                states.append(str(bridge.axis_status(axis)["state"]))
            except EtherRosError:
                states.append("unknown")
        names_done = [axis.name for axis in chosen]
        if errors:
            return False, "; ".join(errors), names_done, states
        what = f"{command} {mode}" if command == "set_mode" else command
        done = ", ".join(f"{n}: {s}" for n, s in zip(names_done, states, strict=True))
        return True, f"{what} done ({done})", names_done, states

    def _on_axis_service(
        self, command: str, req: AxisCommand.Request, resp: AxisCommand.Response
    ) -> AxisCommand.Response:
        try:
            self._lease.check_token(req.lease)
            resp.success, resp.message, resp.joints, resp.states = self.axis_command(
                command, list(req.joints)
            )
        except LeaseRefused as exc:
            resp.success, resp.message = False, f"{command} refused: {exc}"
        except Exception as exc:  # a service must always answer
            resp.success, resp.message = False, f"{command} failed: {exc}"
        return resp

    def _on_set_mode(self, req: SetMode.Request, resp: SetMode.Response) -> SetMode.Response:
        try:
            self._lease.check_token(req.lease)
            resp.success, resp.message, resp.joints, resp.states = self.axis_command(
                "set_mode", list(req.joints), req.mode.strip().lower()
            )
        except LeaseRefused as exc:
            resp.success, resp.message = False, f"set_mode refused: {exc}"
        except Exception as exc:
            resp.success, resp.message = False, f"set_mode failed: {exc}"
        return resp

    def set_extras(self, joint: str, names: list[str], values: list[float]) -> tuple[bool, str]:
        """Command writable extras of one axis in SI units, all in the same cycle, checked
        as ``Axis.set_extras`` checks them: (success, message). Like ``joint_command``:
        refused before the bus lock when not active, written under it."""
        try:
            if len(names) != len(values):
                raise bridge.AxisRejected(f"{len(names)} extra name(s) but {len(values)} value(s)")
            if len(set(names)) != len(names):
                raise bridge.AxisRejected("an extra is named twice")
            if not joint:
                raise bridge.AxisRejected("set_extras needs the joint (one axis)")
            self._axes_if_active()
            with self._bus_lock:
                (axis,) = bridge.select_axes(self._axes_if_active(), [joint])
                axis.set_extras(dict(zip(names, values, strict=True)))
                self._last_command = time.monotonic()
        except EtherRosError as exc:
            return False, str(exc)
        done = ", ".join(f"{n}={v:g}" for n, v in zip(names, values, strict=True))
        return True, f"{joint}: {done or 'nothing'} written"

    def _on_set_extras(
        self, req: SetExtras.Request, resp: SetExtras.Response
    ) -> SetExtras.Response:
        try:
            self._lease.check_token(req.lease)
            resp.success, resp.message = self.set_extras(
                req.joint, list(req.names), [float(v) for v in req.values]
            )
        except LeaseRefused as exc:
            resp.success, resp.message = False, f"set_extras refused: {exc}"
        except Exception as exc:  # a service must always answer
            resp.success, resp.message = False, f"set_extras failed: {exc}"
        return resp

    # ------------------------------------------------------------------------ commands
    def _on_command(self, req: Command.Request, resp: Command.Response) -> Command.Response:
        command = req.command.strip().lower()
        failure: BaseException | None = None
        try:
            if command != "panic":  # panic from anyone; everything else needs the lease
                self._lease.check_token(req.lease)
            self._last_failure = None
            if command.startswith(SET_PARAMETER_COMMAND + " "):
                # The name and value keep their case (an interface name may have capitals).
                command = SET_PARAMETER_COMMAND
                resp.success, resp.message = self._set_parameter_command(req.command)
            else:
                resp.success, resp.message = self.run_command(command)
            # A refused transition answers the AL status code of the slave that refused it.
            failure = None if resp.success else self._last_failure
        except LeaseRefused as exc:
            resp.success, resp.message, failure = False, f"{command} refused: {exc}", exc
        except Exception as exc:  # a service must always answer
            resp.success, resp.message, failure = False, f"{command} failed: {exc}", exc
        return error_fields.fill(resp, failure)

    def _set_parameter_command(self, command: str) -> tuple[bool, str]:
        """``set_parameter NAME VALUE`` (VALUE in JSON: 10, 2.5, true, "eth0"): the holder's
        parameter write while the lease is on (the token is checked by the caller)."""
        parts = command.strip().split(None, 2)
        if len(parts) != 3:
            return False, f"usage: {SET_PARAMETER_COMMAND} NAME VALUE (VALUE in JSON)"
        _, name, text = parts
        try:
            value = json.loads(text)
        except ValueError:
            return False, f'{name}: the value {text[:40]!r} is not JSON (10, 2.5, true, "eth0")'
        if isinstance(value, list | dict) or value is None:
            return False, f"{name}: the value must be a number, a boolean or a string"
        ok, message = self.set_parameters_with_lease(name, value)
        if ok:
            self.get_logger().info(f"parameter {message} (by the lease holder)")
        return ok, message

    def run_command(self, command: str) -> tuple[bool, str]:
        state = self.lifecycle_state()
        if command == "start":
            if state == "active":
                return True, "already running"
            if state == "unconfigured" and not self._transition("configure"):
                return False, self._last_error or "configure failed"
            if not self._transition("activate"):
                return False, self._last_error or "activate failed"
            return True, "running: slaves in OP"
        if command == "stop":
            if state != "active":
                return True, f"not running ({state})"
            self._transition("deactivate")
            return True, "stopped: safe outputs sent, slaves left OP"
        if command == "restart":
            if state == "active":
                self._transition("deactivate")
            return self.run_command("start")
        if command == "panic":
            return self.panic()
        if command == "clear_panic":
            return self.clear_panic()
        if command == "reset_watchdog":
            self._last_command = time.monotonic()
            return True, "command watchdog fed"
        if command in _TRANSITIONS:
            if not self._transition(command):
                return False, self._last_error or f"{command} failed in state {state}"
            return True, f"{command}: now {self.lifecycle_state()}"
        return False, (
            f"unknown command '{command}' (start, stop, restart, panic, clear_panic, "
            f"reset_watchdog, {', '.join(_TRANSITIONS)}, {SET_PARAMETER_COMMAND} NAME VALUE)"
        )

    def _transition(self, name: str) -> bool:
        trigger = getattr(self, f"trigger_{name}")
        result = trigger()
        return bool(result == TransitionCallbackReturn.SUCCESS)

    def panic(self) -> tuple[bool, str]:
        bus = self._bus
        self._panic = True
        if bus is None or not getattr(bus, "running", False):
            return True, "panic latched (no cyclic exchange running)"
        bus.panic()
        self.get_logger().error("PANIC: safe outputs on the wire")
        return True, "safe outputs on the wire until the panic is cleared"

    def clear_panic(self) -> tuple[bool, str]:
        bus = self._bus
        self._panic = False
        if bus is not None and getattr(bus, "running", False):
            bus.clear_panic()
        self._last_command = time.monotonic()
        return True, CLEARED_MESSAGE

    def _on_panic(self, req: Trigger.Request, resp: Trigger.Response) -> Trigger.Response:
        try:
            resp.success, resp.message = self.panic()
        except Exception as exc:
            resp.success, resp.message = False, f"panic failed: {exc}"
        return resp

    # ------------------------------------------------------------------------ SDO
    def _sdo_target(self, slave: str) -> Any:
        spec = self._spec
        if self._bus is None or spec is None:
            raise EtherRosError(f"the node is {self.lifecycle_state()}: no bus open")
        try:
            return spec.slave(slave).name
        except LayoutError as exc:
            raise EtherRosError(str(exc)) from None

    def _on_sdo_read(self, req: SdoRead.Request, resp: SdoRead.Response) -> SdoRead.Response:
        """Upload the object as raw bytes, then decode it with the requested type, or the type
        the ESI dictionary gives the object, when that is a number."""
        try:
            name = self._sdo_target(req.slave)
            t = data_type(req.type) if req.type.strip() else None
            index, subindex = int(req.index), int(req.subindex)
            # SDO callbacks share the lifecycle's callback group, so the bus cannot be closed
            # under them; no _bus_lock, so writes never wait for a mailbox transfer.
            raw = self._bus.sdo_read(name, index, subindex, "octet_string")
            if t is None:
                t = self._dictionary_type(name, index, subindex)
            data = bytes(raw)
            resp.data = data
            resp.success = True
            resp.message = f"{len(data)} byte(s): {data.hex(' ')}"
            if t is not None and t.kind in ("bool", "int", "uint", "real"):
                nbytes = (t.bit_length + 7) // 8
                if len(data) < nbytes:
                    raise EtherRosError(
                        f"{name} {format_address(index, subindex)}: {len(data)} byte(s) read, "
                        f"{t.name} needs {nbytes}"
                    )
                value = dt.decode_value(t, data[:nbytes], t.bit_length)
                resp.value = float(value)  # type: ignore[arg-type]
                resp.message = f"{value} ({t.name})"
        except (EtherRosError, ValueError, TypeError) as exc:
            resp.success, resp.message = False, str(exc)
            error_fields.fill(resp, exc)  # an SDO abort answers its abort code
        return resp

    def _dictionary_type(self, slave: str, index: int, subindex: int) -> dt.DataType | None:
        device = getattr(self._bus.slave(slave), "device", None)
        entry = device.od_entry(index, subindex) if device is not None else None
        return dt.BY_CODE.get(entry.data_type) if entry is not None else None

    def _on_sdo_write(self, req: SdoWrite.Request, resp: SdoWrite.Response) -> SdoWrite.Response:
        from ether_ros.ros.layout import VariableSpec
        from ether_ros.ros.values import parse_text, type_range

        try:
            self._lease.check_token(req.lease)
            name = self._sdo_target(req.slave)
            lo, hi = type_range(req.type)
            address = format_address(req.index, req.subindex)
            var = VariableSpec(address, req.type, req.index, req.subindex, 0, lo, hi)
            value = to_python(parse_text(req.value, var), req.type)
            self._bus.sdo_write(name, int(req.index), int(req.subindex), value, req.type)
            resp.success, resp.message = True, f"{name} {address} = {value}"
        except LeaseRefused as exc:
            resp.success, resp.message = False, f"sdo_write refused: {exc}"
            error_fields.fill(resp, exc)
        except (EtherRosError, ValueError, InvalidValue) as exc:
            resp.success, resp.message = False, str(exc)
            error_fields.fill(resp, exc)  # an SDO abort answers its abort code
        return resp

    # ------------------------------------------------------------------------ lease
    def _on_lease(self, req: Lease.Request, resp: Lease.Response) -> Lease.Response:
        try:
            answer = self._lease.request(
                req.operation, req.holder, req.ttl_s, req.token, bytes(req.gids), req.writer_nodes
            )
        except Exception as exc:  # a service must always answer
            resp.success, resp.message = False, f"lease failed: {exc}"
            return resp
        resp.success, resp.message = answer.success, answer.message
        resp.token, resp.holder, resp.ttl_s = answer.token, answer.holder, answer.ttl_s
        resp.remaining_s, resp.enabled = answer.remaining_s, answer.enabled
        return resp

    def _refuse_change_state(self, req: Any, resp: Any) -> Any:
        self.get_logger().warning(
            "change_state refused: the control lease is on; run lifecycle transitions through "
            "ethercat_communicator (configure, activate, deactivate, cleanup) with the lease"
        )
        resp.success = False
        return resp

    def _stop_motion(self, why: str) -> None:
        """The lease lapsed: stop as ``on_stop`` says (bridge.stop_motion). The running goal and
        topic trajectory end first with the cause, which their joints' state cannot tell."""
        for name, axis in list(getattr(self, "_axes", {}).items()):
            with contextlib.suppress(EtherRosError):
                if bridge.axis_status(axis)["state"] == "operation_enabled":
                    self._stop_cause[name] = "a lapse of the control lease"
        action = getattr(self, "_trajectory_action", None)
        if action is not None:
            action.end_goals("control lease lapsed")
        if getattr(self, "_topic_trajectory", None) is not None:
            self._end_topic_trajectory(None, "control lease lapsed")
        try:
            bridge.stop_motion(self._bus)
        except EtherRosError as exc:
            self.get_logger().error(f"{why}; stopping motion failed: {exc}")
            return
        self.get_logger().warning(f"{why}: motion stopped (on_stop, safe outputs)")

    def _warn_refused(self, what: str, message: str) -> None:
        """One log line per refused topic request, at most one per second per kind: a flood
        of bad requests must not turn into a flood of log lines."""
        self.get_logger().warning(f"{what} refused: {message}", throttle_duration_sec=1.0)

    def lease_status(self) -> dict[str, Any]:
        return self._lease.status()


def command_priority(cfg: Any) -> int:
    """SCHED_FIFO priority of the native command thread: ``ros.command_priority``, kept below
    the engine's real-time thread so a burst of commands never delays a cycle (0: normal). An
    engine without real-time scheduling (policy ``other``) gets no real-time command thread
    either, since it would then run ahead of the cyclic loop."""
    wanted = int(cfg.ros.command_priority)
    realtime = cfg.bus.realtime
    if not wanted or realtime.policy == "other":
        return 0
    if realtime.policy == "deadline":
        return wanted  # SCHED_DEADLINE runs ahead of every SCHED_FIFO thread
    cap = int(realtime.priority) - 1
    return min(wanted, cap) if cap >= 1 else 0


def config_parameters(cfg: Any) -> dict[str, Any]:
    """The configuration as flat ROS parameters (``bus.cycle_us``, ``slaves.<name>.position``,
    ...). Values ROS parameters cannot hold (null, lists of mappings) are left out."""
    data = cfg.model_dump(mode="json")
    out: dict[str, Any] = {}
    _flatten("bus", data.get("bus", {}), out)
    _flatten("ros", data.get("ros", {}), out)
    if data.get("esi"):
        out["esi"] = [str(p) for p in data["esi"]]
    for s in data.get("slaves", []):
        base = f"slaves.{s['name']}"
        for key in ("position", "alias", "vendor_id", "product_code", "revision", "device"):
            if s.get(key) is not None:
                out[f"{base}.{key}"] = s[key]
        _flatten(f"{base}.safe_outputs", s.get("safe_outputs") or {}, out)
        joints = [j["name"] for j in s.get("joints") or []]
        if joints:
            out[f"{base}.joints"] = joints
    out.update(axis_parameters(cfg))
    return out


def axis_parameters(cfg: Any) -> dict[str, Any]:
    """The CiA 402 axes as parameters (``axis_joints``, ``axes.<joint>.mode``, ``.slave``,
    ``.position_limits``, ``.velocity_limit``, ``.torque_limit``): what a client (the console)
    checks a joint command against before sending it."""
    out: dict[str, Any] = {}
    names = []
    for slave in cfg.slaves:
        for axis in getattr(slave, "axes", None) or []:
            names.append(axis.name)
            base = f"axes.{axis.name}"
            out[f"{base}.slave"] = slave.name
            out[f"{base}.mode"] = axis.mode
            out[f"{base}.position_limits"] = [float(x) for x in axis.position_limits]
            out[f"{base}.velocity_limit"] = float(axis.velocity_limit)
            out[f"{base}.torque_limit"] = float(axis.torque_limit)
    if names:
        out["axis_joints"] = names
    return out


def _flatten(prefix: str, value: Any, out: dict[str, Any]) -> None:
    if isinstance(value, dict):
        for k, v in value.items():
            _flatten(f"{prefix}.{k}", v, out)
    elif value is None:
        return
    elif isinstance(value, list):
        if value and all(isinstance(v, str) for v in value):
            out[prefix] = list(value)
    else:
        out[prefix] = value


def spin(node: EtherRosNode, threads: int = 4) -> None:
    """Run the node until shutdown (Ctrl-C / SIGTERM): the lifecycle node on a multi-threaded
    executor in this thread, its command node (if any) on a single-threaded executor in another."""
    executor = rclpy.executors.MultiThreadedExecutor(num_threads=threads, context=node.context)
    executor.add_node(node)
    commands: Any = None
    command_thread: threading.Thread | None = None
    if node.command_node is not None:
        commands = rclpy.executors.SingleThreadedExecutor(context=node.context)
        commands.add_node(node.command_node)
        command_thread = threading.Thread(
            target=_serve_commands, args=(commands,), name="ether_ros-commands", daemon=True
        )
        command_thread.start()
    try:
        executor.spin()
    finally:
        if commands is not None:
            commands.shutdown()
        if command_thread is not None:
            command_thread.join(timeout=2)
        executor.shutdown()


def _serve_commands(executor: Any) -> None:
    # Ahead of the node's other Python threads (and other processes) for the CPU, so a command
    # waiting for the CPU on a loaded machine is not queued behind the sample publishing.
    with contextlib.suppress(OSError):  # not root / no CAP_SYS_NICE: normal priority
        os.setpriority(os.PRIO_PROCESS, threading.get_native_id(), COMMAND_THREAD_NICE)
    while True:
        try:
            executor.spin()  # returns once the executor is shut down
            return
        except (ExternalShutdownException, KeyboardInterrupt):
            return  # the context was shut down: the node is going away
        except Exception:  # one failing command must not end the command path
            log.exception("serving a command failed")
