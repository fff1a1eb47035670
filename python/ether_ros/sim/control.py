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

Every request is validated against the tables below (operation, fault kind, argument names,
types and ranges, slave names) before it reaches the simulator; nothing is ever evaluated or
passed to a shell.
"""

from __future__ import annotations

import contextlib
import json
import os
import socket
import threading
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ether_ros._native.protocol import cia402
from ether_ros.errors import EtherRosError

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


REQUIRED = object()  # an argument without default
OMIT = object()  # an optional argument passed on only when given


@dataclass(frozen=True)
class Arg:
    kind: type  # int, float or bool (or str for a slave: name or position → position)
    lo: float | None = None
    hi: float | None = None
    default: Any = REQUIRED
    choices: tuple[str, ...] = ()  # a name out of these (instead of a slave)


# Faults of a CiA 402 drive (the simulator's `cia402` model), by the name `drive_fault` takes.
DRIVE_FAULTS = ("over_current", "encoder", "under_voltage", "following_error")
# Axes of one drive (ETG.6010, the protocol crate's limit); the model checks its own count.
MAX_AXES = cia402.MAX_AXES


# Fault kinds and their arguments: the names passed on to SimNetwork.fault(kind, **args).
FAULTS: dict[str, dict[str, Arg]] = {
    "drop": {"rate": Arg(float, 0.0, 1.0), "burst": Arg(int, 1, 1_000_000, 1)},
    "corrupt": {"rate": Arg(float, 0.0, 1.0), "bytes": Arg(int, 1, 64, 1)},
    "delay": {"us": Arg(int, 0, 1_000_000)},
    "reset": {"slave": Arg(str)},
    "refuse_op": {"slave": Arg(str), "on": Arg(bool, default=True)},
    "link": {"up": Arg(bool), "at": Arg(str, default=OMIT), "port": Arg(int, 0, 3, default=OMIT)},
    "drift_step": {"slave": Arg(str), "ppm": Arg(float, -1000.0, 1000.0)},
    "stall_mailbox": {"slave": Arg(str), "on": Arg(bool, default=True)},
    "drive_fault": {
        "slave": Arg(str),
        "error": Arg(str, choices=DRIVE_FAULTS),
        "axis": Arg(int, 1, MAX_AXES, 1),
    },
    "seed": {"seed": Arg(int, 0, 2**63 - 1)},
    "clear": {},
}
QUERIES = ("stats", "slave_info", "probe")


def _check_value(name: str, spec: Arg, value: Any, slaves: Sequence[str]) -> Any:
    if spec.choices:
        if not isinstance(value, str) or value not in spec.choices:
            raise ControlError(
                f"{name}: unknown value {value!r} (known: {', '.join(spec.choices)})"
            )
        return value
    if spec.kind is str:  # a slave: name or position
        if isinstance(value, bool):
            raise ControlError(f"{name}: expected a slave name or position, got {value!r}")
        if isinstance(value, int):
            if not 0 <= value < len(slaves):
                raise ControlError(f"{name}: no slave at position {value} (0..{len(slaves) - 1})")
            return value
        if isinstance(value, str):
            if value.isascii() and value.isdigit():
                return _check_value(name, spec, int(value), slaves)
            if value in slaves:
                return slaves.index(value)
            raise ControlError(f"{name}: no slave named {value!r} (slaves: {', '.join(slaves)})")
        raise ControlError(f"{name}: expected a slave name or position, got {value!r}")
    if spec.kind is bool:
        if not isinstance(value, bool):
            raise ControlError(f"{name}: expected true or false, got {value!r}")
        return value
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise ControlError(f"{name}: expected a number, got {value!r}")
    if spec.kind is int:
        if isinstance(value, float) and not value.is_integer():
            raise ControlError(f"{name}: expected an integer, got {value!r}")
        value = int(value)
    else:
        value = float(value)
    if (spec.lo is not None and value < spec.lo) or (spec.hi is not None and value > spec.hi):
        raise ControlError(f"{name}: {value} is outside [{spec.lo}, {spec.hi}]")
    return value


def validate_fault(kind: str, args: dict[str, Any], slaves: Sequence[str]) -> dict[str, Any]:
    """Checked keyword arguments for ``SimNetwork.fault(kind, **result)``."""
    table = FAULTS.get(kind)
    if table is None:
        raise ControlError(f"unknown fault {kind!r} (known: {', '.join(FAULTS)})")
    unknown = set(args) - set(table)
    if unknown:
        raise ControlError(
            f"fault {kind}: unknown argument(s) {', '.join(sorted(unknown))}"
            f" (takes: {', '.join(table) or 'nothing'})"
        )
    out: dict[str, Any] = {}
    for name, spec in table.items():
        if name in args:
            out[name] = _check_value(name, spec, args[name], slaves)
        elif spec.default is REQUIRED:
            raise ControlError(f"fault {kind}: missing argument {name}")
        elif spec.default is not OMIT:
            out[name] = spec.default
    return out


def validate_request(request: Any, slaves: Sequence[str]) -> tuple[str, str, dict[str, Any]]:
    """``(op, kind, args)`` of a decoded JSON request, or :class:`ControlError`."""
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
        return op, "", {}
    if op in ("slave_info", "probe"):
        if set(rest) != {"slave"}:
            raise ControlError(f"{op} takes exactly one argument: slave")
        return op, "", {"slave": _check_value("slave", Arg(str), rest["slave"], slaves)}
    raise ControlError(f"unknown op {op!r} (known: fault, {', '.join(QUERIES)})")


Handler = Callable[[str, str, dict[str, Any]], Any]


class ControlServer:
    """Serves the control socket on a background thread; ``handler(op, kind, args)`` does the
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
