"""A running master's answers to the inspection tools beside it.

While a :class:`~ether_ros.master.bus.Bus` holds its interface (``ether_ros.claim``), the
inspection commands of another process (``ether-ros slaves``, ``states``, ``upload``,
``download``, ``reg-read``, ``sii-read``, ``master``, ...) do not open the interface — that
would be a second master, and the slaves of the running one would drop under it. They send
their requests here instead, and this module carries them out on the running bus's own
acyclic worker (``worker.py``: the same datagram queue and the same mailbox owner as the
master's own requests, so a slave's mailbox has one owner and its counter stays in step, and
a request for one slave never waits for another slave's exchange). Reads never disturb the cycle;
a write (an SDO download) is refused while the bus's write gate says so (the ROS node's
control lease).

Requests and answers (``ether_ros.claim`` carries them as JSON lines):

=========== ============================================ ==========================================
op          arguments                                    answer
=========== ============================================ ==========================================
``who``     —                                            pid, command, interface, node, since
``found``   —                                            the slaves as found on the wire (SII)
``states``  —                                            each slave's AL state and status code
``reg_read``  ``position``, ``address``, ``length``      ``{"hex": ...}``
``upload``  ``position``, ``index``, ``subindex``        ``{"hex": ...}``
``download`` ``position``, ``index``, ``subindex``, hex  ``null``
``entry``   ``position``, ``index``, ``subindex``        name, data type, bit length (its ESI)
``stats``   —                                            the engine's counters, groups, supervisor
=========== ============================================ ==========================================
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import TYPE_CHECKING, Any

from ether_ros.claim import InterfaceClaim, hex_bytes
from ether_ros.errors import BusError, EtherRosError

if TYPE_CHECKING:
    from ether_ros.master.bus import Bus
    from ether_ros.master.slave import Slave

#: The ESC's address space a register read may cover (registers, then process data RAM).
ESC_ADDRESS_SPACE = 0x10000
#: Longest register read in one request (one datagram's data).
MAX_REGISTER_READ = 1024


class RequestRefused(EtherRosError):
    """The running master refuses a request (a write while writes are not allowed)."""


def serve_bus(claim: InterfaceClaim, bus: Bus) -> None:
    """Answer the inspection requests of other processes on ``claim`` from ``bus``."""
    handlers: dict[str, Callable[[Mapping[str, Any]], Any]] = {
        "found": lambda _r: [_found(s) for s in bus.slaves],
        "states": lambda _r: [s.as_dict() for s in bus.states()],
        "reg_read": lambda r: _reg_read(bus, r),
        "upload": lambda r: _upload(bus, r),
        "download": lambda r: _download(bus, r),
        "entry": lambda r: _entry(bus, r),
        "stats": lambda _r: bus.stats(),
    }
    for op, handler in handlers.items():
        claim.serve(op, handler)


def _found(s: Slave) -> dict[str, Any]:
    f = s.found
    return {
        "position": f.position,
        "station": f.station,
        "alias": f.alias,
        "esc_type": f.esc_type,
        "esc_features": f.esc_features,
        "dl_status": f.dl_status,
        "sii": f.sii.hex(),
        "name": s.name,
    }


def _int(request: Mapping[str, Any], key: str, lo: int, hi: int) -> int:
    value = request.get(key)
    if isinstance(value, bool) or not isinstance(value, int) or not lo <= value <= hi:
        raise RequestRefused(f"{key} must be an integer {lo}..{hi}, got {value!r}")
    return value


def _slave(bus: Bus, request: Mapping[str, Any]) -> Slave:
    position = _int(request, "position", 0, 0xFFFF)
    for s in bus.slaves:
        if s.position == position:
            return s
    raise RequestRefused(f"no slave at position {position} on the running bus")


def _reg_read(bus: Bus, request: Mapping[str, Any]) -> bytes:
    s = _slave(bus, request)
    address = _int(request, "address", 0, ESC_ADDRESS_SPACE - 1)
    length = _int(request, "length", 1, MAX_REGISTER_READ)
    if address + length > ESC_ADDRESS_SPACE:
        raise RequestRefused(
            f"0x{address:04X} + {length} bytes runs past the ESC's address space (0xFFFF)"
        )
    # One datagram through the bus's acyclic worker: it shares a frame with the master's own.
    data, wkc = bus.dg.fprd(s.station, address, length)
    if wkc != 1:
        raise BusError(f"{s}: no answer reading 0x{address:04X}")
    return bytes(data)


def _mailbox(s: Slave) -> Any:
    if s.sdo is None:
        raise BusError(f"{s}: has no CoE mailbox on the running bus")
    return s.sdo


def _upload(bus: Bus, request: Mapping[str, Any]) -> bytes:
    s = _slave(bus, request)
    index = _int(request, "index", 0, 0xFFFF)
    subindex = _int(request, "subindex", 0, 0xFF)
    data: bytes = _mailbox(s).upload(index, subindex)
    return data


def _entry(bus: Bus, request: Mapping[str, Any]) -> dict[str, Any] | None:
    """An object entry as the running master's ESI describes it (None: not described)."""
    s = _slave(bus, request)
    index = _int(request, "index", 0, 0xFFFF)
    subindex = _int(request, "subindex", 0, 0xFF)
    e = s.device.od_entry(index, subindex) if s.device is not None else None
    if e is None:
        return None
    return {"name": e.name, "data_type": e.data_type, "bit_length": e.bit_length}


def _download(bus: Bus, request: Mapping[str, Any]) -> None:
    s = _slave(bus, request)
    index = _int(request, "index", 0, 0xFFFF)
    subindex = _int(request, "subindex", 0, 0xFF)
    why_not = bus.remote_write_refusal()
    if why_not:
        raise RequestRefused(f"{s}: download refused by the running master: {why_not}")
    try:
        data = hex_bytes(request.get("data", ""))
    except ValueError:
        raise RequestRefused("data must be hex bytes") from None
    if not data:
        raise RequestRefused("no data to download")
    _mailbox(s).download(index, subindex, data)
