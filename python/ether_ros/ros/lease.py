"""The control lease: one client commands the robot, everyone can stop it (docs/security.md).

As robot SDKs do it: a client acquires the lease (service ``lease``, ``ether_ros_msgs/Lease``)
with a time to live and keeps it alive by renewing it; while the node's lease is on
(``ros.lease.enabled``), only the holder's writes, joint commands, trajectories, SDO writes,
mode changes, axis services and lifecycle commands are accepted, and everyone else is refused
with the holder's name. ``panic`` is accepted from anyone; ``clear_panic`` needs the lease. The
operator console can take the lease over. When the lease lapses (its holder stopped renewing
it: crashed, hung, cut off) motion stops as each axis's ``on_stop`` says and every slave's
outputs go back to their configured safe values (the cyclic exchange goes on; the next holder
commands again). A holder that releases the lease hands control back deliberately: the outputs
stay as it left them, as when a client ends without a lease (the command watchdog,
``command_timeout_ms``, is the guard for a client that stops commanding).

Who is who:

- a service request carries the holder's token (the ``lease`` field of the project's services);
- a message on a command topic is the holder's when its publisher is one of the holder's: the
  GID rmw reports with each message (``rmw_message_info_t.publisher_gid``) is checked against
  the GIDs the holder registered (``gids``, which :class:`~ether_ros.ros.client.EtherRosClient`
  fills in with its own publishers') or those of the nodes it named (``writer_nodes``, looked
  up in the ROS graph; e.g. a ``topic_based_ros2_control`` node publishing ``joint_commands``).

The state every entry point checks is ``_native.LeaseGate`` (crates/commands/src/lease.rs): the
native command threads read it without a lock and without the GIL for each message, Python for
each service call; this module is the policy that writes it. Nothing here authenticates anyone:
without DDS security any participant can claim a holder's name or GIDs (docs/security.md).
"""

from __future__ import annotations

import ctypes
import logging
import math
import secrets
import threading
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from typing import Any

from ether_ros import _native
from ether_ros.errors import EtherRosError

log = logging.getLogger(__name__)

#: Operations of the ``lease`` service.
OPERATIONS = ("acquire", "renew", "release", "takeover", "status")
#: How often the lease thread looks for a lapse and refreshes the holder's publishers.
POLL_S = 0.02
#: How often the holder's ``writer_nodes`` are looked up again in the ROS graph (their
#: publishers may be discovered after the lease was granted).
REFRESH_S = 0.2
GID_LEN = int(_native.LeaseGate.GID_LEN)
MAX_WRITERS = int(_native.LeaseGate.MAX_WRITERS)
#: Longest holder name accepted.
MAX_HOLDER = 128


class LeaseRefused(EtherRosError):
    """A command from someone who does not hold the control lease (names the holder)."""


@dataclass(frozen=True)
class LeaseAnswer:
    """The ``lease`` service's answer (the fields of ``Lease.Response``)."""

    success: bool
    message: str
    token: int = 0
    holder: str = ""
    ttl_s: float = 0.0
    remaining_s: float = 0.0
    enabled: bool = False


# Looks up the GIDs of the publishers of the given nodes on the command topics.
WriterLookup = Callable[[Sequence[str]], list[bytes]]
# What happens when nobody holds the lease any more: (why) -> None.
StopMotion = Callable[[str], None]


def _now_ns() -> int:
    return time.clock_gettime_ns(time.CLOCK_MONOTONIC)


class ControlLease:
    """The lease policy of one node; ``gate`` is what the command paths check."""

    def __init__(
        self,
        enabled: bool,
        ttl_s: float,
        max_ttl_s: float,
        *,
        stop_motion: StopMotion,
        lookup_writers: WriterLookup,
        now_ns: Callable[[], int] = _now_ns,
    ) -> None:
        self.gate = _native.LeaseGate()
        self.gate.set_enabled(enabled)
        self.enabled = enabled
        self.default_ttl_s = float(ttl_s)
        self.max_ttl_s = float(max_ttl_s)
        self._stop_motion = stop_motion
        self._lookup_writers = lookup_writers
        self._now_ns = now_ns
        self._lock = threading.Lock()
        self._holder = ""
        self._token = 0
        self._ttl_s = 0.0
        self._gids: list[bytes] = []
        self._writer_nodes: list[str] = []
        self._expires_ns = 0
        self._last_refresh_ns = 0
        self.counters = {"granted": 0, "taken_over": 0, "released": 0, "lapsed": 0, "refused": 0}
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    # ------------------------------------------------------------------------ lifetime
    def start(self) -> None:
        """Watch for a lapse in a thread of its own (not an executor: a topic flood must not
        delay the stop)."""
        if self.enabled and self._thread is None:
            self._thread = threading.Thread(target=self._watch, name="ether_ros-lease", daemon=True)
            self._thread.start()

    def close(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2)
            self._thread = None

    def _watch(self) -> None:
        while not self._stop.wait(POLL_S):
            try:
                self.poll()
            except Exception:  # the watcher must outlive one failed stop or lookup
                log.exception("lease watcher")

    # ------------------------------------------------------------------------ checks
    def check_token(self, token: int) -> None:
        """LeaseRefused (naming the holder) unless a service request carrying ``token`` may
        command now."""
        self._verdict(*self.gate.check_token(int(token) & 0xFFFF_FFFF_FFFF_FFFF, self._now_ns()))

    def check_publisher(self, publisher: bytes | None) -> None:
        """LeaseRefused unless a message from ``publisher`` (its GID; None: unknown, a message
        taken by rclpy, which does not report it) may command now."""
        if not self.enabled:
            return
        if publisher is None:
            with self._lock:
                self.counters["refused"] += 1
            raise LeaseRefused(
                "the control lease needs the native command path to tell publishers apart, "
                "and it is not running for this topic"
            )
        self._verdict(*self.gate.check_gid(bytes(publisher), self._now_ns()))

    def check_goal_sender(self, sender: bytes | None) -> None:
        """LeaseRefused unless the action client that sent a goal (the GID of its goal-reply
        reader, see :func:`request_sender`; None: unknown) is the holder's. Before refusing,
        the holder's ``writer_nodes`` are looked up again: the holder may have made its action
        client since the last look."""
        if not self.enabled:
            return
        if sender is None:
            self._verdict(
                "refused",
                "the control lease cannot tell who sent this goal (this rclpy does not show "
                "the request's sender): goals are refused while the lease is on",
            )
            return
        verdict, _ = self.gate.check_gid(bytes(sender), self._now_ns())
        if verdict != "allowed":
            self.refresh_writers()
        self._verdict(*self.gate.check_gid(bytes(sender), self._now_ns()))

    def _verdict(self, verdict: str, text: str) -> None:
        if verdict != "allowed":
            with self._lock:
                self.counters["refused"] += 1
            raise LeaseRefused(text)

    def holder(self) -> str:
        """The current holder's name ("" when nobody holds it)."""
        with self._lock:
            return self._holder if self._expires_ns else ""

    def status(self) -> dict[str, Any]:
        """For the diagnostics: enabled, holder, remaining time and the counters."""
        with self._lock:
            now = self._now_ns()
            remaining = max(0.0, (self._expires_ns - now) / 1e9) if self._expires_ns else 0.0
            return {
                "enabled": self.enabled,
                "holder": self._holder if self._expires_ns else "",
                "remaining_s": remaining,
                "writers": len(self._gids),
                **self.counters,
            }

    # ------------------------------------------------------------------------ service
    def request(
        self,
        operation: str,
        holder: str,
        ttl_s: float,
        token: int,
        gids: bytes | Sequence[int],
        writer_nodes: Iterable[str],
    ) -> LeaseAnswer:
        """One ``lease`` service request (see Lease.srv). Never raises for bad input: the
        answer says what is wrong."""
        op = operation.strip().lower()
        if op not in OPERATIONS:
            return self._answer(False, f"unknown operation {operation!r} ({', '.join(OPERATIONS)})")
        if not self.enabled:
            return self._answer(
                op == "status",
                "the control lease is off on this node (ros.lease.enabled): everyone may command",
            )
        if op == "status":
            return self._answer(True, self._describe())
        try:
            if op in ("acquire", "takeover"):
                name = _check_holder(holder)
                ttl = self._ttl(ttl_s)
                writer_list = _check_nodes(writer_nodes)
                gid_list = _split_gids(bytes(gids))
                return self._grant(op, name, ttl, gid_list, writer_list)
            if op == "renew":
                return self._renew(int(token), ttl_s, bytes(gids), writer_nodes)
            return self._release(int(token))
        except LeaseRefused as exc:
            return self._answer(False, str(exc))

    def _ttl(self, ttl_s: float) -> float:
        if not isinstance(ttl_s, int | float) or math.isnan(ttl_s) or ttl_s < 0:
            raise LeaseRefused(f"ttl_s must be a number >= 0 (0: the default), got {ttl_s!r}")
        if ttl_s == 0:
            return self.default_ttl_s
        return min(float(ttl_s), self.max_ttl_s)

    def _grant(
        self, op: str, holder: str, ttl: float, gids: list[bytes], writer_nodes: list[str]
    ) -> LeaseAnswer:
        found = self._lookup(writer_nodes)
        with self._lock:
            now = self._now_ns()
            held = self._expires_ns and now < self._expires_ns
            if held and op == "acquire":
                self.counters["refused"] += 1
                return self._answer_locked(
                    False,
                    f"the control lease is held by '{self._holder}' "
                    f"({(self._expires_ns - now) / 1e9:.1f} s left): take it over or wait",
                )
            previous = self._holder if held else ""
            self._holder, self._ttl_s, self._token = holder, ttl, _new_token()
            self._gids, self._writer_nodes = gids, writer_nodes
            self._expires_ns = now + int(ttl * 1e9)
            self._publish_locked(found)
            self.counters["taken_over" if previous else "granted"] += 1
            what = f"taken over from '{previous}'" if previous else "granted"
            answer = self._answer_locked(
                True, f"lease {what} to '{holder}' for {ttl:g} s", grantee=True
            )
        if previous:
            log.warning("control lease taken over from '%s' by '%s'", previous, holder)
        else:
            log.info("control lease granted to '%s' (%g s)", holder, ttl)
        return answer

    def _renew(
        self, token: int, ttl_s: float, gids: bytes, writer_nodes: Iterable[str]
    ) -> LeaseAnswer:
        ttl = self._ttl(ttl_s) if ttl_s else 0.0
        nodes = _check_nodes(writer_nodes)
        gid_list = _split_gids(gids)
        found = self._lookup(nodes or self._writer_nodes)
        with self._lock:
            now = self._now_ns()
            if not self._mine(token, now):
                return self._answer_locked(False, self._refusal_locked(now))
            if ttl:
                self._ttl_s = ttl
            if gid_list:
                self._gids = gid_list
            if nodes:
                self._writer_nodes = nodes
            self._expires_ns = now + int(self._ttl_s * 1e9)
            self._publish_locked(found)
            return self._answer_locked(True, f"lease of '{self._holder}' renewed", grantee=True)

    def _release(self, token: int) -> LeaseAnswer:
        with self._lock:
            now = self._now_ns()
            if not self._mine(token, now):
                return self._answer_locked(False, self._refusal_locked(now))
            holder = self._holder
            self._end_locked()
            self.counters["released"] += 1
        log.info("control lease released by '%s'", holder)
        return self._answer(True, f"lease of '{holder}' released")

    # ------------------------------------------------------------------------ lapse
    def poll(self) -> None:
        """Stop motion once the lease has lapsed; look the holder's nodes up again now and
        then (their publishers may appear after the grant)."""
        if not self.enabled:
            return
        now = self._now_ns()
        lapsed = ""
        nodes: list[str] = []
        with self._lock:
            if self._expires_ns and now >= self._expires_ns:
                lapsed = self._holder
                self._end_locked()
                self.counters["lapsed"] += 1
            elif (
                self._expires_ns
                and self._writer_nodes
                and now - self._last_refresh_ns >= REFRESH_S * 1e9
            ):
                self._last_refresh_ns = now
                nodes = list(self._writer_nodes)
        if lapsed:
            log.warning("control lease of '%s' lapsed: stopping motion", lapsed)
            self._stop_motion(f"the control lease of '{lapsed}' lapsed")
            return
        if nodes:
            found = self._lookup(nodes)
            with self._lock:
                if self._expires_ns and self._writer_nodes == nodes:
                    self._publish_locked(found)

    def refresh_writers(self) -> None:
        """Look the holder's ``writer_nodes`` up in the graph now (an entry point about to
        refuse a sender calls it once: the holder may have made the sender since the last
        look)."""
        with self._lock:
            nodes = list(self._writer_nodes) if self._expires_ns else []
        if not nodes:
            return
        found = self._lookup(nodes)
        with self._lock:
            if self._expires_ns and self._writer_nodes == nodes:
                self._last_refresh_ns = self._now_ns()
                self._publish_locked(found)

    # ------------------------------------------------------------------------ helpers
    def _lookup(self, nodes: Sequence[str]) -> list[bytes]:
        if not nodes:
            return []
        try:
            return [g for g in self._lookup_writers(nodes) if len(g) == GID_LEN]
        except Exception as exc:  # the graph is best effort; registered GIDs still count
            log.warning("looking up the publishers of %s: %s", ", ".join(nodes), exc)
            return []

    def _mine(self, token: int, now: int) -> bool:
        return bool(self._expires_ns) and now < self._expires_ns and token == self._token

    def _refusal_locked(self, now: int) -> str:
        if self._expires_ns and now < self._expires_ns:
            return f"the control lease is held by '{self._holder}' (not this token)"
        if self._holder:
            return f"the control lease of '{self._holder}' lapsed or was released: acquire it again"
        return "nobody holds the control lease: acquire it"

    def _end_locked(self) -> None:
        self._expires_ns = 0
        self._token = 0
        self._gids, self._writer_nodes = [], []
        self.gate.revoke()

    def _publish_locked(self, found: list[bytes]) -> None:
        gids = list(dict.fromkeys([*self._gids, *found]))[:MAX_WRITERS]
        self.gate.grant(self._holder, self._token, gids, self._expires_ns)

    def _describe(self) -> str:
        with self._lock:
            now = self._now_ns()
            if self._expires_ns and now < self._expires_ns:
                left = (self._expires_ns - now) / 1e9
                return f"held by '{self._holder}' ({left:.1f} s left)"
            return "nobody holds the control lease"

    def _answer(self, success: bool, message: str) -> LeaseAnswer:
        with self._lock:
            return self._answer_locked(success, message)

    def _answer_locked(self, success: bool, message: str, grantee: bool = False) -> LeaseAnswer:
        """The answer; the token only to its ``grantee`` (acquire, takeover, renew), never to
        whoever asks for the status."""
        now = self._now_ns()
        held = bool(self._expires_ns) and now < self._expires_ns
        return LeaseAnswer(
            success=success,
            message=message,
            token=self._token if success and held and grantee else 0,
            holder=self._holder if held else "",
            ttl_s=self._ttl_s if held else 0.0,
            remaining_s=(self._expires_ns - now) / 1e9 if held else 0.0,
            enabled=self.enabled,
        )


def _new_token() -> int:
    return secrets.randbits(63) | 1  # never 0 (0 means "no lease")


def _check_holder(holder: str) -> str:
    name = holder.strip()
    if not name:
        raise LeaseRefused("holder: give a name (e.g. the client node's full name)")
    if len(name) > MAX_HOLDER or any(ord(c) < 0x20 or ord(c) == 0x7F for c in name):
        raise LeaseRefused(
            f"holder: at most {MAX_HOLDER} characters and no control characters, got {name!r:.60}"
        )
    return name


def _check_nodes(nodes: Iterable[str]) -> list[str]:
    out = []
    for n in nodes:
        if not n.startswith("/") or len(n) > 256 or any(ord(c) < 0x21 for c in n):
            raise LeaseRefused(f"writer_nodes: {n!r:.60} is not a full node name (/ns/name)")
        out.append(n)
    if len(out) > MAX_WRITERS:
        raise LeaseRefused(f"writer_nodes: at most {MAX_WRITERS} nodes")
    return out


def _split_gids(data: bytes) -> list[bytes]:
    if len(data) % GID_LEN:
        raise LeaseRefused(f"gids: {len(data)} bytes is not a whole number of {GID_LEN}-byte GIDs")
    gids = [data[i : i + GID_LEN] for i in range(0, len(data), GID_LEN)]
    if len(gids) > MAX_WRITERS:
        raise LeaseRefused(f"gids: at most {MAX_WRITERS} publishers")
    return gids


def own_publisher_gids(node: Any, topics: Iterable[str]) -> bytes:
    """The GIDs (16 bytes each, concatenated) of ``node``'s own publishers on ``topics``: what
    a client registers with its lease so its command messages count as the holder's."""
    name, namespace = node.get_name(), node.get_namespace()
    out = b""
    for topic in topics:
        for info in node.get_publishers_info_by_topic(topic):
            if info.node_name == name and info.node_namespace == namespace:
                out += bytes(info.endpoint_gid)[:GID_LEN]
    return out


def graph_writer_gids(
    node: Any, topics: Sequence[str], goal_reply_topics: Sequence[str] = ()
) -> WriterLookup:
    """A lookup of the publishers of named nodes on ``topics`` in ``node``'s view of the graph,
    and of their action clients' goal-reply readers on ``goal_reply_topics`` (DDS names, see
    :func:`goal_reply_topic`): what identifies the sender of an action goal (request_sender)."""

    def lookup(nodes: Sequence[str]) -> list[bytes]:
        wanted = set(nodes)
        gids = []
        endpoints = [info for t in topics for info in node.get_publishers_info_by_topic(t)]
        for topic in goal_reply_topics:
            endpoints += node.get_subscriptions_info_by_topic(topic, no_mangle=True)
        for info in endpoints:
            ns = info.node_namespace.rstrip("/")
            if f"{ns}/{info.node_name}" in wanted:
                gids.append(bytes(info.endpoint_gid)[:GID_LEN])
        return gids

    return lookup


#: How a DDS topic of an action's goal replies ends (``rr<action>/_action/send_goalReply``).
GOAL_REPLY_SUFFIX = "/_action/send_goalReply"


def goal_reply_topic(action: str) -> str:
    """The DDS topic on which the clients of ``action`` (its full name) read goal replies."""
    return f"rr{action}{GOAL_REPLY_SUFFIX}"


def own_goal_reply_gids(node: Any) -> bytes:
    """The GIDs of ``node``'s action clients' goal-reply readers (every action): registered with
    a lease so that the node's action goals count as the holder's."""
    name, namespace = node.get_name(), node.get_namespace()
    out = b""
    for topic, _types in node.get_subscriber_names_and_types_by_node(
        name, namespace, no_demangle=True
    ):
        if topic.endswith(GOAL_REPLY_SUFFIX):
            for info in node.get_subscriptions_info_by_topic(topic, no_mangle=True):
                if info.node_name == name and info.node_namespace == namespace:
                    out += bytes(info.endpoint_gid)[:GID_LEN]
    return out


# Where pybind11 keeps the pointer to a wrapped C++ value: right after the object's header.
_PYBIND_VALUE_OFFSET = 16


def request_sender(header: Any) -> bytes | None:
    """Who sent a service or action-goal request: ``rmw_request_id_t.writer_guid`` of its
    header, which Fast DDS fills in with the client's reply reader's GID (the one the graph
    lists on the reply topic). rclpy (Jazzy) wraps the struct but shows only its
    ``sequence_number``, so the 16 bytes are read from the wrapped struct; the sequence number
    stored right after them checks the read. None when it does not match (an rclpy that wraps
    it otherwise): the lease then refuses, saying it cannot tell who sent the goal."""
    try:
        pointer = ctypes.c_void_p.from_address(id(header) + _PYBIND_VALUE_OFFSET).value
        if not pointer:
            return None
        seq = ctypes.c_int64.from_address(pointer + GID_LEN).value
        if seq != int(header.sequence_number):
            return None
        return ctypes.string_at(pointer, GID_LEN)
    except (AttributeError, TypeError, ValueError, OverflowError):
        return None
