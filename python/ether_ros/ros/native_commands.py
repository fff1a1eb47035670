"""The node's command path for ``pdo_listener`` and ``joint_commands``: native threads, not the
Python executor.

A ``WriteVariable`` taken by the Python executor waits for the GIL, which the sample publisher
holds most of the time on a node that publishes every cycle; that cost milliseconds per command.
Here the subscription is served by ``ether_ros._native.CommandReceiver`` (crates/commands): a
thread that waits on the rcl subscription itself, decodes the message, and — when it is
certainly valid — writes it into the engine's output buffer and answers on ``write_results``
without touching Python. Every other request (text values, unknown names, values out of range)
is handed to :meth:`EtherRosNode._on_write_topic` in order, through a Python thread here, so all
refusals and their wording stay in one place (``bridge.resolve_write``).

``joint_commands`` (``sensor_msgs/JointState`` for CiA 402 axes) has a receiver of its own
(``message="joint_state"``): certainly valid commands go straight into the engine's axis command
slots, structurally invalid ones are refused natively; the rest go to
:meth:`EtherRosNode._on_joint_commands` (``bridge.resolve_joint_command``). ``joint_trajectory``
takes the native path too (``message="passthrough"``), only for who-may and fairness: every
trajectory goes to Python.

Every receiver checks the control lease (``lease``, a ``_native.LeaseGate``) for each message by
its publisher's GID before anything else, and queues what it defers per publisher, served round
robin, so one flooding publisher never delays another's commands (docs/ros.md, "The command
path"). The deferred handler gets the message and its publisher's GID.

The rcl objects are created with rclpy's low-level API so no executor ever waits on (and takes
from) the same subscription; they are marked in use while the thread runs, so rclpy cannot
destroy them under it.
"""

from __future__ import annotations

import logging
import os
import threading
import time
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

from ether_ros_msgs.msg import WriteVariable
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.qos import QoSProfile
from rclpy.serialization import deserialize_message
from rclpy.type_support import check_is_valid_msg_type

from ether_ros import _native
from ether_ros.errors import EtherRosError
from ether_ros.master import workspace
from ether_ros.master.bus import output_bit_offset
from ether_ros.ros import bridge
from ether_ros.ros.layout import BusSpec

log = logging.getLogger(__name__)

# How long the Python thread waits for a deferred request before looking at its stop flag.
_POLL_S = 0.1


class CommandPathError(EtherRosError):
    """The native command path could not be set up (names what is missing)."""


def loaded_library(stem: str, maps: str | Path = "/proc/self/maps") -> str:
    """The path of ``<stem>.so`` as loaded into this process (rclpy loads librcl and
    librcutils from the ROS installation or the wheels)."""
    name = f"{stem}.so"
    for line in Path(maps).read_text().splitlines():
        path = line.split(maxsplit=5)[-1] if line.count(" ") >= 5 else ""
        if Path(path).name == name or Path(path).name.startswith(name + "."):
            return path
    raise CommandPathError(f"{name} is not loaded in this process (is rclpy imported?)")


#: The native decoder's name of each message type it checks (``_native.check_command_message``).
_CHECKED_MESSAGES = {
    "WriteVariable": "write_variable",
    "JointState": "joint_state",
    "JointTrajectory": "joint_trajectory",
}


def message_problem(data: bytes, message_type: Any) -> str | None:
    """Why a serialized command message is refused before rclpy turns it into Python, or None.

    rclpy cuts every string at its first NUL (``strlen``) and replaces bytes that are not UTF-8,
    so ``Kp100_knee\\0junk`` would reach Python as ``Kp100_knee`` and be applied. The native
    decoder (``crates/commands/src/cdr.rs``) reads the bytes as they are and names the field."""
    kind = _CHECKED_MESSAGES.get(message_type.__name__)
    if kind is None:
        return None
    try:
        _native.check_command_message(kind, data)
    except ValueError as exc:
        return str(exc)
    return None


def checked_message(data: bytes, message_type: Any) -> tuple[Any, str | None]:
    """(message, problem): the deserialized message (None if even rclpy cannot read it) and
    why it is refused (None: it may be handled)."""
    problem = message_problem(data, message_type)
    try:
        message = deserialize_message(data, message_type)
    except Exception as exc:  # rclpy's deserializer raises its own errors for garbage
        return None, problem or f"not a {message_type.__name__}: {exc}"
    return message, problem


def _kind(variable: Any) -> str | None:
    """The native encoding of a bus ``ProcessVariable``, None if it is not a number."""
    t = variable.dtype
    if t.kind in ("bool", "int", "uint"):
        return str(t.kind)
    if t.kind == "real":
        return {32: "real32", 64: "real64"}.get(int(variable.bit_length))
    return None


def command_table(bus: Any, spec: BusSpec) -> Any:
    """The bus's output variables as ``_native.CommandTable`` rows: where each one is in the
    process image (from the bus's layout) and the range the node accepts (from ``spec``, the
    same ``VariableSpec`` the Python path checks against)."""
    rows: list[tuple[str, int, list[_native._VariableRow]]] = []
    for s, slave in zip(spec.slaves, bus.slaves, strict=True):
        if s.name != slave.name:
            raise CommandPathError(f"layout order differs: {s.name} vs {slave.name}")
        area, layout = slave.area, slave.layout
        if area is None or layout is None or not s.outputs:
            rows.append((s.name, s.position, []))
            continue
        variables = []
        ruled = workspace.ruled_outputs(
            slave.device.type_name if slave.device is not None else "",
            [(v.name, v.index, v.subindex) for v in layout.outputs],
        )
        for v, pv in zip(s.outputs, layout.outputs, strict=True):
            kind = _kind(pv)
            if kind is None:
                continue  # not a number: every write goes to Python (which refuses it)
            variables.append(
                (
                    pv.name,
                    pv.index,
                    pv.subindex,
                    output_bit_offset(slave, pv),
                    int(pv.bit_length),
                    kind,
                    float(v.minimum),
                    float(v.maximum),
                    pv.name in ruled,
                )
            )
        rows.append((s.name, s.position, variables))
    return _native.CommandTable(rows)


def joint_table(axes: dict[str, Any]) -> Any:
    """The axes as a ``_native.JointTable``: each one's engine index, limits and the setpoint
    kind its mode takes (the same the Python path checks against)."""
    return _native.JointTable(bridge.joint_rows(axes))


# Fast DDS names its receive threads "dds.shm.<port>" and "dds.udp.<port>" (2.14, Jazzy).
_MIDDLEWARE_RECEIVERS = ("dds.shm.", "dds.udp.")


def raise_middleware_receivers(
    priority: int, cpus: set[int] | None = None, tasks: str | Path = "/proc/self/task"
) -> list[str]:
    """Give the middleware's receive threads of this process SCHED_FIFO ``priority`` and keep
    them on ``cpus`` (the command thread's CPUs).

    A command reaches the native thread through one of them (it takes the sample off the shared
    memory or socket and wakes the waiting thread); at normal priority it waits behind the
    node's Python threads for a CPU. Returns the threads changed; without CAP_SYS_NICE none is,
    and the command path just has a longer tail."""
    if priority <= 0:
        return []
    changed = []
    for task in Path(tasks).iterdir():
        try:
            name = (task / "comm").read_text().strip()
            if name.startswith(_MIDDLEWARE_RECEIVERS):
                if cpus:
                    os.sched_setaffinity(int(task.name), cpus)
                os.sched_setscheduler(int(task.name), os.SCHED_FIFO, os.sched_param(priority))
                changed.append(name)
        except (OSError, ValueError):
            continue  # thread gone, or not permitted
    return changed


class RefusalBudget:
    """Refusals answered per publisher (by GID), as the native threads budget theirs: a burst
    of ``CommandReceiver.REFUSAL_ANSWERS_PER_S``, then that many a second; beyond it a flooding
    publisher's refusals are counted, not answered, so the flood does not turn into as many
    answers. Kept for the ``ANSWER_BUDGETS`` publishers refused most recently. In all, at most
    ``REFUSAL_ANSWERS_TOTAL_PER_S`` answers a second, however many publishers flood: every
    client's answers share the results topic (``QOS_RESULTS``)."""

    def __init__(self, clock: Callable[[], float] = time.monotonic) -> None:
        self.rate = float(_native.CommandReceiver.REFUSAL_ANSWERS_PER_S)
        self.size = int(_native.CommandReceiver.ANSWER_BUDGETS)
        self.total_rate = float(_native.CommandReceiver.REFUSAL_ANSWERS_TOTAL_PER_S)
        self._total: tuple[float, float] | None = None  # (tokens, last), None: full
        self._clock = clock
        self._lock = threading.Lock()
        self._budgets: dict[bytes, tuple[float, float]] = {}
        self.unanswered = 0

    def spend(self, publisher: bytes | None) -> bool:
        """Take one answer from ``publisher``'s budget; False when it is spent. A request
        without a known publisher (a topic rclpy serves) is always answered."""
        if publisher is None:
            return True
        now = self._clock()
        with self._lock:
            tokens, last = self._budgets.pop(publisher, (self.rate, now))
            tokens = min(self.rate, tokens + (now - last) * self.rate)
            ok = tokens >= 1.0
            self._budgets[publisher] = (tokens - 1.0 if ok else tokens, now)
            if ok:
                total, last_total = self._total or (self.total_rate, now)
                total = min(self.total_rate, total + (now - last_total) * self.total_rate)
                ok = total >= 1.0
                self._total = (total - 1.0 if ok else total, now)
            if len(self._budgets) > self.size:  # forget the least recently refused
                del self._budgets[next(iter(self._budgets))]
            if not ok:
                self.unanswered += 1
            return ok


def housekeeping_cpus(rt_cpu: int | None) -> set[int]:
    """The CPUs this process may use other than the real-time thread's: where the command path
    runs. Empty (no pinning) when the RT thread is not pinned or no other CPU is left.

    Keeping the command path off the RT thread's CPU means it never waits for a cycle there,
    and on a virtual machine the wake-ups along the path (middleware thread, command thread)
    stay on the same CPUs instead of crossing to the RT CPU (measured in docs/benchmarks.md)."""
    if rt_cpu is None:
        return set()
    return set(os.sched_getaffinity(0)) - {rt_cpu}


class NativeCommandPath:
    """``pdo_listener`` (or, with ``message_type=JointState``, ``joint_commands``) for one node:
    the native receiver plus the Python thread that handles what it defers
    (``handle_deferred`` gets the deserialized message; ``handle_refused`` gets the message, or
    None when it cannot be read at all, and the reason, for one the native decoder refuses)."""

    def __init__(
        self,
        node: Any,
        topic: str,
        qos: QoSProfile,
        results_publisher: Any,
        handle_deferred: Callable[[Any, bytes], None],
        priority: int,
        cpus: set[int] | None = None,
        message_type: Any = WriteVariable,
        kind: str | None = None,
        lease: Any = None,
        handle_refused: Callable[..., None] | None = None,
    ) -> None:
        self._handle_deferred = handle_deferred
        self._handle_refused = handle_refused
        self._message_type = message_type
        if kind is None:
            kind = "write_variable" if message_type is WriteVariable else "joint_state"
        self._joints: Any = None
        check_is_valid_msg_type(message_type)  # loads the type support the subscription needs
        with node.handle:
            self._subscription = _rclpy.Subscription(
                node.handle, message_type, topic, qos.get_c_qos_profile()
            )
        # Held "in use" until close(): rclpy defers destroying them (node destruction,
        # shutdown) until then, so the native thread never sees a freed object.
        self._in_use = [node.context.handle, self._subscription, results_publisher.handle]
        for handle in self._in_use:
            handle.__enter__()
        try:
            self.receiver = _native.CommandReceiver(
                librcl=loaded_library("librcl"),
                librcutils=loaded_library("librcutils"),
                context=node.context.handle.pointer,
                subscription=self._subscription.pointer,
                results=results_publisher.handle.pointer,
                priority=priority,
                cpus=sorted(cpus or ()),
                message=kind,
                lease=lease,
            )
        except (RuntimeError, CommandPathError) as exc:
            self._release()
            raise CommandPathError(f"starting the native command path: {exc}") from None
        # The same priority for the middleware threads that deliver the commands.
        raise_middleware_receivers(priority, cpus)
        self._stop = threading.Event()
        self._thread = threading.Thread(
            target=self._serve_deferred,
            name={"write_variable": "ether_ros-deferred", "joint_state": "ether_ros-jdeferred"}.get(
                kind, "ether_ros-tdeferred"
            ),
            daemon=True,
        )
        self._thread.start()

    def attach(self, bus: Any, spec: BusSpec) -> None:
        """Write valid requests into ``bus``'s engine from now on."""
        self.receiver.attach(bus.engine, command_table(bus, spec))

    def attach_joints(self, bus: Any, axes: dict[str, Any]) -> None:
        """Write valid joint commands into ``bus``'s axes from now on."""
        self._joints = joint_table(axes)
        self.receiver.attach(bus.engine, self._joints)

    def hold_joints(self, axes: dict[str, Any], held: list[Any]) -> None:
        """Leave every command for the ``held`` axes to Python (while their mode changes);
        ``axes`` are all of them, in the table's order."""
        joints = self._joints
        if joints is None:
            return
        for i, axis in enumerate(axes.values()):
            if axis in held:
                joints.set_kind(i, None)

    def set_held(self, axes: dict[str, Any], held: set[str] | frozenset[str]) -> None:
        """Leave every command for the joints named in ``held`` to Python, take the others'
        setpoint kinds from their modes; ``axes`` are all of them, in the table's order."""
        joints = self._joints
        if joints is None:
            return
        for i, (name, axis) in enumerate(axes.items()):
            joints.set_kind(i, None if name in held else bridge.setpoint_kind(axis))

    def set_causes(self, axes: dict[str, Any], causes: Mapping[str, str]) -> None:
        """What stopped each axis that it did not ask to stop, by joint (the node's
        ``_stop_cause``): the native path names it when it refuses a command to the axis.
        ``axes`` are all of them, in the table's order."""
        joints = self._joints
        if joints is None:
            return
        for i, name in enumerate(axes):
            joints.set_cause(i, causes.get(name, ""))

    def update_joints(self, axes: dict[str, Any]) -> None:
        """Take each axis's setpoint kind from its mode again (after a mode change)."""
        joints = self._joints
        if joints is None:
            return
        for i, axis in enumerate(axes.values()):
            joints.set_kind(i, bridge.setpoint_kind(axis))

    def detach(self) -> None:
        """No more native writes (returns once none is in progress)."""
        self.receiver.detach()
        self._joints = None

    def last_command_ns(self) -> int:
        return int(self.receiver.last_command_ns())

    def counters(self) -> dict[str, int]:
        return dict(self.receiver.counters())

    def close(self) -> None:
        """Stop both threads and release the subscription (idempotent)."""
        if self._stop.is_set():
            return
        self._stop.set()
        self.receiver.stop()
        self._thread.join(timeout=5)
        self._release()

    def _release(self) -> None:
        for handle in reversed(self._in_use):
            handle.__exit__(None, None, None)
        self._in_use = []
        self._subscription.destroy_when_not_in_use()

    def waiting_publishers(self) -> int:
        return int(self.receiver.waiting_publishers())

    def _serve_deferred(self) -> None:
        while not self._stop.is_set():
            taken = self.receiver.next_deferred(_POLL_S)
            if taken is None:
                continue
            data, publisher = taken
            try:
                message, problem = checked_message(data, self._message_type)
                if problem is None:
                    self._handle_deferred(message, publisher)
                elif self._handle_refused is not None:
                    self._handle_refused(message, problem, publisher=publisher)
                else:
                    log.warning("%s refused: %s", self._message_type.__name__, problem)
            except Exception:  # one bad request must not end the command path
                log.exception("handling a deferred request failed")
            finally:
                self.receiver.deferred_done()
