"""One owner per network interface: a claim that dies with its process.

A master (or a simulator) that holds an interface binds an abstract UNIX socket named after
the role and the interface (``\\0ether_ros/master/eth1``). The kernel allows one socket per
name in a network namespace — the namespace an interface lives in — and removes it when the
process ends, however it ends: nothing is left behind in ``/run`` and no stale lock ever
refuses a new owner. A second owner's bind fails; it connects to the first one instead,
asks who it is, and is refused with a message naming the running process (its PID, its
command line and, for a ROS node, the node's name).

The same socket is the running master's door for the inspection tools (``ether-ros
slaves``, ``upload``, ``reg-read`` ...): a connection sends one JSON object per line,
``{"op": NAME, ...arguments}``, and gets one JSON object per line back, ``{"ok": VALUE}`` or
``{"error": {"type": CLASS, "message": TEXT, "code": CODE}}``. Only the owner's user (or
root) may connect (the peer's credentials, ``SO_PEERCRED``, are checked on every
connection): an abstract socket has no file permissions of its own.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import socket
import struct
import sys
import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

from ether_ros.errors import EtherRosError

log = logging.getLogger(__name__)

#: Roles that claim an interface: a master drives the bus; a simulator answers it.
ROLES = ("master", "sim")
#: Longest request or answer line (an SII image of 64 KiB in hex fits).
MAX_LINE = 1 << 20
#: How long a client waits for the owner's answer (an SDO transfer may take seconds).
ANSWER_TIMEOUT_S = 30.0


class InterfaceBusy(EtherRosError):
    """The interface is held by another process of the same role; ``owner`` describes it
    (``pid``, ``command``, ``node`` where it has one)."""

    def __init__(self, interface: str, role: str, owner: Mapping[str, Any]) -> None:
        self.interface = interface
        self.role = role
        self.owner = dict(owner)
        noun = "simulator" if role == "sim" else role
        super().__init__(
            f"another {noun} is already running on {interface} ({describe_owner(owner)}): "
            f"{_advice(role)}"
        )


class OwnerError(EtherRosError):
    """The interface's owner refused or failed a request: ``kind`` is the owner's error class,
    ``code`` its code (an AL status code, an SDO abort code ...) where it has one."""

    def __init__(self, kind: str, message: str, code: int | None = None) -> None:
        self.kind = kind
        self.code = code
        super().__init__(message)


def _advice(role: str) -> str:
    if role == "master":
        return (
            "stop it first; the inspection commands (slaves, states, upload, reg-read, "
            "sii-read, master ...) answer through it while it runs"
        )
    return "stop it first: two simulators on one link would answer every frame twice"


def describe_owner(owner: Mapping[str, Any]) -> str:
    """``pid 1234, ether-ros run ..., node /ether_comm`` from an owner's ``who`` answer."""
    parts = [f"pid {owner.get('pid', '?')}"]
    if owner.get("command"):
        parts.append(str(owner["command"]))
    if owner.get("node"):
        parts.append(f"node {owner['node']}")
    return ", ".join(parts)


def socket_name(role: str, interface: str) -> str:
    """The abstract socket name of ``role`` on ``interface`` (leading NUL: abstract)."""
    if role not in ROLES:
        raise ValueError(f"unknown role {role!r}")
    return f"\0ether_ros/{role}/{interface}"


def _command_line() -> str:
    """This process's command line, shortened for a message."""
    argv = [os.path.basename(sys.argv[0]) if sys.argv else "python", *sys.argv[1:]]
    text = " ".join(argv)
    return text if len(text) <= 120 else text[:117] + "..."


Handler = Callable[[Mapping[str, Any]], Any]


@dataclass
class InterfaceClaim:
    """This process's claim on ``interface`` as ``role``; serves requests to ``handlers``
    (op name → function of the request, returning a JSON value) until released."""

    interface: str
    role: str
    info: dict[str, Any] = field(default_factory=dict)
    handlers: dict[str, Handler] = field(default_factory=dict)
    _sock: socket.socket | None = None
    _thread: threading.Thread | None = None

    @classmethod
    def take(cls, interface: str, role: str = "master", **info: Any) -> InterfaceClaim:
        """Claim ``interface``; raises :class:`InterfaceBusy` naming the owner when another
        process of ``role`` holds it."""
        name = socket_name(role, interface)
        for _attempt in range(3):
            sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM | socket.SOCK_CLOEXEC)
            try:
                sock.bind(name)
            except OSError as exc:
                sock.close()
                if exc.errno != 98:  # EADDRINUSE: someone holds it
                    raise EtherRosError(f"{interface}: cannot claim it: {exc.strerror}") from None
                try:
                    owner = ask(interface, "who", role=role, timeout=5.0)
                except (ConnectionError, FileNotFoundError):
                    # The owner is going away between our bind and our connect: try again.
                    time.sleep(0.05)
                    continue
                except EtherRosError as err:
                    owner = {"pid": "?", "command": f"not answering: {err}"}
                raise InterfaceBusy(interface, role, owner) from None
            sock.listen(8)
            claim = cls(interface, role)
            claim.info = {
                "pid": os.getpid(),
                "command": _command_line(),
                "interface": interface,
                "since": time.time(),
                **info,
            }
            claim.handlers = {"who": claim._who}
            claim._sock = sock
            claim._thread = threading.Thread(
                target=claim._serve, name=f"ether_ros-{role}-claim", daemon=True
            )
            claim._thread.start()
            return claim
        raise EtherRosError(f"{interface}: cannot claim it: its owner keeps changing")

    def _who(self, _request: Mapping[str, Any]) -> dict[str, Any]:
        return dict(self.info)

    def serve(self, op: str, handler: Handler) -> None:
        """Answer requests ``op`` with ``handler``."""
        self.handlers[op] = handler

    def release(self) -> None:
        """Give the interface up (the socket name is free again at once)."""
        sock, self._sock = self._sock, None
        if sock is not None:
            with contextlib.suppress(OSError):
                sock.shutdown(socket.SHUT_RDWR)
            sock.close()

    def __enter__(self) -> InterfaceClaim:
        return self

    def __exit__(self, *exc: object) -> None:
        self.release()

    # ---- serving ------------------------------------------------------------------------

    def _serve(self) -> None:
        while True:
            sock = self._sock
            if sock is None:
                return
            try:
                conn, _ = sock.accept()
            except OSError:
                return
            threading.Thread(
                target=self._connection, args=(conn,), name="ether_ros-claim-conn", daemon=True
            ).start()

    def _connection(self, conn: socket.socket) -> None:
        with conn:
            if not _peer_allowed(conn):
                _send(conn, _error_answer("PermissionError", "not the owner's user or root"))
                return
            reader = conn.makefile("rb")
            while True:
                line = reader.readline(MAX_LINE + 1)
                if not line:
                    return
                if len(line) > MAX_LINE:
                    _send(conn, _error_answer("RequestError", "request line too long"))
                    return
                try:
                    _send(conn, self._answer(line))
                except OSError:
                    return

    def _answer(self, line: bytes) -> dict[str, Any]:
        try:
            request = json.loads(line)
        except (ValueError, UnicodeDecodeError):
            return _error_answer("RequestError", "a request is one JSON object per line")
        if not isinstance(request, dict) or not isinstance(request.get("op"), str):
            return _error_answer("RequestError", 'a request needs "op": NAME')
        handler = self.handlers.get(request["op"])
        if handler is None:
            known = ", ".join(sorted(self.handlers))
            return _error_answer(
                "RequestError", f"unknown request {request['op']!r} (this {self.role}: {known})"
            )
        try:
            return {"ok": handler(request)}
        except EtherRosError as exc:
            code = getattr(exc, "code", None)
            code = code if isinstance(code, int) else None
            return _error_answer(type(exc).__name__, str(exc), code)
        except Exception as exc:  # the owner's bug must not end its service, nor pass silently
            log.exception("request %r failed", request.get("op"))
            return _error_answer(type(exc).__name__, f"{request['op']} failed: {exc}")


def _peer_allowed(conn: socket.socket) -> bool:
    """Root or this process's own user only: an abstract socket has no file permissions."""
    try:
        creds = conn.getsockopt(socket.SOL_SOCKET, socket.SO_PEERCRED, struct.calcsize("3i"))
    except OSError:
        return False
    _pid, uid, _gid = struct.unpack("3i", creds)
    return uid in (0, os.geteuid())


def _error_answer(kind: str, message: str, code: int | None = None) -> dict[str, Any]:
    return {"error": {"type": kind, "message": message, "code": code}}


def _send(conn: socket.socket, answer: Mapping[str, Any]) -> None:
    conn.sendall(json.dumps(answer, default=_json_value).encode() + b"\n")


def _json_value(value: Any) -> Any:
    if isinstance(value, bytes | bytearray):
        return {"hex": bytes(value).hex()}
    return str(value)


# ---- the client side ------------------------------------------------------------------------


class OwnerClient:
    """A connection to the process that holds an interface."""

    def __init__(self, interface: str, role: str = "master", timeout: float = ANSWER_TIMEOUT_S):
        self.interface = interface
        self.role = role
        self._sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM | socket.SOCK_CLOEXEC)
        self._sock.settimeout(timeout)
        try:
            self._sock.connect(socket_name(role, interface))
        except OSError:
            self._sock.close()
            raise
        self._reader = self._sock.makefile("rb")
        self.owner: dict[str, Any] = {}

    @classmethod
    def find(cls, interface: str, role: str = "master") -> OwnerClient | None:
        """A client of the owner of ``interface``, or None when nobody holds it."""
        try:
            client = cls(interface, role)
        except OSError:
            return None
        try:
            client.owner = client.request("who")
        except (OSError, EtherRosError):
            client.close()
            return None
        return client

    def request(self, op: str, **args: Any) -> Any:
        """Send request ``op``; the owner's answer, or its error raised as :class:`OwnerError`."""
        try:
            self._sock.sendall(json.dumps({"op": op, **args}).encode() + b"\n")
            line = self._reader.readline(MAX_LINE + 1)
        except TimeoutError:
            raise EtherRosError(
                f"{self.interface}: the {self.role} did not answer {op!r} in time"
            ) from None
        if not line:
            raise ConnectionError(f"{self.interface}: the {self.role} closed the connection")
        answer = json.loads(line)
        if "error" in answer:
            err = answer["error"]
            raise OwnerError(str(err.get("type")), str(err.get("message")), err.get("code"))
        return answer.get("ok")

    def close(self) -> None:
        self._reader.close()
        self._sock.close()

    def __enter__(self) -> OwnerClient:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def ask(interface: str, op: str, role: str = "master", timeout: float = 5.0, **args: Any) -> Any:
    """One request to the owner of ``interface`` (raises ConnectionError when there is none)."""
    client = OwnerClient(interface, role, timeout)
    try:
        return client.request(op, **args)
    finally:
        client.close()


def hex_bytes(value: Any) -> bytes:
    """Bytes sent as ``{"hex": ...}`` (see ``_json_value``) or a hex string, back to bytes."""
    if isinstance(value, dict):
        value = value.get("hex", "")
    return bytes.fromhex(str(value))
