"""Control socket of a running simulator: fault injection and read-only queries.

``ether-ros sim`` listens on a unix stream socket (default
``/run/ether_ros/sim-<interface>.sock``). A client sends one JSON object per line and gets one
JSON object per line back::

    {"op": "fault", "kind": "drop", "rate": 0.01, "burst": 2}   -> {"ok": true}
    {"op": "fault", "kind": "reset", "slave": "hind_left_leg"}  -> {"ok": true}
    {"op": "fault", "kind": "drive_fault", "slave": 0, "axis": 2, "error": "encoder"}
                                                                 -> {"ok": true}
    {"op": "stats"}                                              -> {"ok": true, "result": {...}}
    {"op": "slave_info", "slave": 1}                             -> {"ok": true, "result": {...}}
    {"op": "probe", "slave": 0}                                  -> {"ok": true, "result": {...}}
    anything wrong                                               -> {"ok": false, "error": "..."}

Every request is validated before it reaches the simulator: the operation and the fault kind
against the tables below, slave names against the bus, and the fault's arguments (names,
types, ranges, defaults) by the fault type it becomes (``ether_ros._native.Drop``, ...,
crates/py/src/sim_faults.rs); nothing is ever evaluated or passed to a shell.
"""

from __future__ import annotations

import contextlib
import json
import os
import socket
import threading
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from ether_ros._native import (
    Clear,
    Corrupt,
    Delay,
    DriftStep,
    DriveFault,
    Drop,
    Link,
    RefuseOp,
    Reset,
    Seed,
    StallMailbox,
)
from ether_ros._native.protocol import cia402
from ether_ros.errors import EtherRosError

# Any fault `SimNetwork.inject` takes.
Fault = (
    Drop
    | Corrupt
    | Delay
    | Reset
    | RefuseOp
    | Link
    | DriftStep
    | StallMailbox
    | DriveFault
    | Seed
    | Clear
)

RUN_DIR = Path("/run/ether_ros")
MAX_REQUEST = 4096


class ControlError(EtherRosError):
    """A control request is invalid or the simulator cannot be reached."""


def socket_path(interface: str) -> Path:
    return RUN_DIR / f"sim-{interface}.sock"


class InterfaceLock:
    """One simulator per interface: the simulator's claim on it (``ether_ros.claim``, an
    abstract socket in the interface's network namespace), held for the simulator's life. A
    second simulator on the same link would answer every frame twice; it is refused, naming
    the running one. The kernel drops the claim when the process ends, however it ends, and
    leaves no file behind."""

    def __init__(self, interface: str) -> None:
        from ether_ros.claim import InterfaceBusy, InterfaceClaim

        try:
            self._claim: Any = InterfaceClaim.take(interface, "sim")
        except InterfaceBusy as exc:
            raise ControlError(str(exc)) from None

    def release(self) -> None:
        if self._claim is not None:
            self._claim.release()
            self._claim = None


# Fault kinds by the name a request gives (`"kind"`), and the types that carry them. Each
# type's constructor (crates/py/src/sim_faults.rs) holds its defaults and range checks, the one
# place they live: a request is turned into one of these and refused with its message.
FAULTS: dict[str, type[Fault]] = {
    "drop": Drop,
    "corrupt": Corrupt,
    "delay": Delay,
    "reset": Reset,
    "refuse_op": RefuseOp,
    "link": Link,
    "drift_step": DriftStep,
    "stall_mailbox": StallMailbox,
    "drive_fault": DriveFault,
    "seed": Seed,
    "clear": Clear,
}
# Arguments that name a slave: a request gives a name or a position, the type a position.
SLAVE_ARGS = frozenset({"slave", "at"})
# Faults of a CiA 402 drive (the simulator's `cia402` model), by the name `drive_fault` takes.
DRIVE_FAULTS: tuple[str, ...] = tuple(DriveFault.ERRORS)
# Axes of one drive (ETG.6010, the protocol crate's limit); the model checks its own count.
MAX_AXES = cia402.MAX_AXES
QUERIES = ("stats", "slave_info", "probe")


def _slave(name: str, value: Any, slaves: Sequence[str]) -> int:
    """The position of the slave that ``value`` (a name or a position) names."""
    if isinstance(value, bool):
        raise ControlError(f"{name}: expected a slave name or position, got {value!r}")
    if isinstance(value, int):
        if not 0 <= value < len(slaves):
            raise ControlError(f"{name}: no slave at position {value} (0..{len(slaves) - 1})")
        return value
    if isinstance(value, str):
        if value.isascii() and value.isdigit():
            return _slave(name, int(value), slaves)
        if value in slaves:
            return slaves.index(value)
        raise ControlError(f"{name}: no slave named {value!r} (slaves: {', '.join(slaves)})")
    raise ControlError(f"{name}: expected a slave name or position, got {value!r}")


def validate_fault(kind: str, args: dict[str, Any], slaves: Sequence[str]) -> Fault:
    """The fault a request names, for ``SimNetwork.inject``; :class:`ControlError` naming the
    unknown, missing or wrong argument otherwise."""
    cls = FAULTS.get(kind)
    if cls is None:
        raise ControlError(f"unknown fault {kind!r} (known: {', '.join(FAULTS)})")
    fields: dict[str, Any] = {
        k: _slave(k, v, slaves) if k in SLAVE_ARGS else v for k, v in args.items()
    }
    try:
        fault = cls(**fields)
    except (TypeError, ValueError, OverflowError) as exc:
        # A wrong type is named in the exception's notes ("while processing 'rate'"), which a
        # reply line would lose otherwise.
        notes = getattr(exc, "__notes__", [])
        raise ControlError(
            f"fault {kind}: {exc}" + (f" ({'; '.join(notes)})" if notes else "")
        ) from None
    # JSON true/false are Python bools, which are ints too: a number field must not take one.
    for name, value in fields.items():
        if isinstance(value, bool) and not isinstance(getattr(fault, name), bool):
            raise ControlError(f"fault {kind}: {name}: expected a number, got {value!r}")
    return fault


def validate_request(request: Any, slaves: Sequence[str]) -> tuple[str, str, Any]:
    """``(op, kind, arg)`` of a decoded JSON request, or :class:`ControlError`: for a fault the
    :data:`Fault` to inject, for a query of one slave its position, for ``stats`` None."""
    if not isinstance(request, dict):
        raise ControlError("a request is a JSON object")
    op = request.get("op")
    rest = {k: v for k, v in request.items() if k != "op"}
    if op == "fault":
        kind = rest.pop("kind", None)
        if not isinstance(kind, str):
            raise ControlError("fault: missing 'kind'")
        return op, kind, validate_fault(kind, rest, slaves)
    if op == "stats":
        if rest:
            raise ControlError("stats takes no arguments")
        return op, "", None
    if op in ("slave_info", "probe"):
        if set(rest) != {"slave"}:
            raise ControlError(f"{op} takes exactly one argument: slave")
        return op, "", _slave("slave", rest["slave"], slaves)
    raise ControlError(f"unknown op {op!r} (known: fault, {', '.join(QUERIES)})")


Handler = Callable[[str, str, Any], Any]


class ControlServer:
    """Serves the control socket on a background thread; ``handler(op, kind, arg)`` does the
    work for validated requests and returns a JSON-serialisable result."""

    def __init__(self, path: Path, slaves: Sequence[str], handler: Handler) -> None:
        self.path = path
        self.slaves = list(slaves)
        self.handler = handler
        self._lock = threading.Lock()
        if path.exists() or path.is_symlink():
            self._remove_stale(path)
        self._sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            self._sock.bind(str(path))
            os.chmod(path, 0o660)
        except OSError as exc:
            self._sock.close()
            raise ControlError(
                f"cannot create the control socket {path}: {exc.strerror or exc}"
                " (run as root, give --control PATH, or --no-control)"
            ) from None
        self._sock.listen(8)
        self._sock.settimeout(0.2)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._serve, name="sim-control", daemon=True)

    @staticmethod
    def _remove_stale(path: Path) -> None:
        probe = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        try:
            probe.connect(str(path))
        except OSError:
            path.unlink()  # nobody listens: left over from a killed simulator
            return
        finally:
            probe.close()
        raise ControlError(f"{path}: another simulator is already running on this interface")

    def start(self) -> None:
        self._thread.start()

    def close(self) -> None:
        self._stop.set()
        # Wake the thread waiting in accept() at once instead of at its next timeout: a
        # connection of our own.
        if self._thread.is_alive():
            with contextlib.suppress(OSError), socket.socket(socket.AF_UNIX) as wake:
                wake.settimeout(0.1)
                wake.connect(str(self.path))
        if self._thread.is_alive():
            self._thread.join(timeout=2)
        self._sock.close()
        with contextlib.suppress(FileNotFoundError):
            self.path.unlink()

    def _serve(self) -> None:
        while not self._stop.is_set():
            try:
                conn, _ = self._sock.accept()
            except TimeoutError:
                continue
            except OSError:
                return
            threading.Thread(target=self._client, args=(conn,), daemon=True).start()

    def _client(self, conn: socket.socket) -> None:
        with conn, conn.makefile("rwb") as f:
            while not self._stop.is_set():
                line = f.readline(MAX_REQUEST + 1)
                if not line:
                    return
                f.write((json.dumps(self.answer(line)) + "\n").encode())
                f.flush()

    def answer(self, line: bytes) -> dict[str, Any]:
        """The reply to one request line (never raises)."""
        if len(line) > MAX_REQUEST:
            return {"ok": False, "error": f"request longer than {MAX_REQUEST} bytes"}
        try:
            request = json.loads(line)
        except (json.JSONDecodeError, UnicodeDecodeError) as exc:
            return {"ok": False, "error": f"not JSON: {exc}"}
        try:
            op, kind, args = validate_request(request, self.slaves)
            with self._lock:
                result = self.handler(op, kind, args)
        except EtherRosError as exc:
            return {"ok": False, "error": str(exc)}
        except (ValueError, TypeError, RuntimeError) as exc:  # from the simulator core
            return {"ok": False, "error": f"simulator: {exc}"}
        return {"ok": True, "result": result} if result is not None else {"ok": True}


def request(path: Path, payload: dict[str, Any], timeout: float = 5.0) -> Any:
    """Send one request to a running simulator and return its result (ControlError if not ok)."""
    s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    s.settimeout(timeout)
    try:
        try:
            s.connect(str(path))
        except OSError as exc:
            raise ControlError(f"no simulator listening on {path}: {exc.strerror or exc}") from None
        with s.makefile("rwb") as f:
            f.write((json.dumps(payload) + "\n").encode())
            f.flush()
            line = f.readline()
    finally:
        s.close()
    if not line:
        raise ControlError(f"{path}: the simulator closed the connection")
    reply = json.loads(line)
    if not reply.get("ok"):
        raise ControlError(str(reply.get("error", "request failed")))
    return reply.get("result")
