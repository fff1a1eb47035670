"""Texts for SDO abort codes (ETG.1000.6, taken over from CiA 301), mailbox error codes and
CoE emergency error codes, so errors name what went wrong instead of a bare number."""

from __future__ import annotations

SDO_ABORT_TEXTS: dict[int, str] = {
    0x05030000: "toggle bit not alternated",
    0x05040000: "SDO protocol timed out",
    0x05040001: "client/server command specifier not valid or unknown",
    0x05040002: "invalid block size",
    0x05040003: "invalid sequence number",
    0x05040004: "CRC error",
    0x05040005: "out of memory",
    0x06010000: "unsupported access to an object",
    0x06010001: "attempt to read a write-only object",
    0x06010002: "attempt to write a read-only object",
    0x06010003: "subindex cannot be written, subindex 0 must be 0 for write access",
    0x06010004: "complete access not supported for this object",
    0x06010005: "object length exceeds the mailbox size",
    0x06010006: "object mapped to an RxPDO, SDO download blocked",
    0x06020000: "object does not exist in the object dictionary",
    0x06040041: "object cannot be mapped to the PDO",
    0x06040042: "number and length of the mapped objects would exceed the PDO length",
    0x06040043: "general parameter incompatibility",
    0x06040047: "general internal incompatibility in the device",
    0x06060000: "access failed because of a hardware error",
    0x06070010: "data type does not match, length of service parameter does not match",
    0x06070012: "data type does not match, length of service parameter too high",
    0x06070013: "data type does not match, length of service parameter too low",
    0x06090011: "subindex does not exist",
    0x06090030: "value range of parameter exceeded",
    0x06090031: "value of parameter written too high",
    0x06090032: "value of parameter written too low",
    0x06090036: "maximum value is less than minimum value",
    0x08000000: "general error",
    0x08000020: "data cannot be transferred or stored to the application",
    0x08000021: "data cannot be transferred or stored because of local control",
    0x08000022: "data cannot be transferred or stored in the present device state",
    0x08000023: "object dictionary not present or cannot be generated",
    0x08000024: "no data available",
}


def sdo_abort_text(code: int) -> str:
    """``0x06020000 object does not exist in the object dictionary``: the code and its meaning."""
    return f"0x{code:08X} {SDO_ABORT_TEXTS.get(code, 'unknown abort code')}"


MAILBOX_ERROR_TEXTS: dict[int, str] = {
    0x0001: "syntax of the 6-byte mailbox header is wrong",
    0x0002: "the mailbox protocol is not supported",
    0x0003: "channel field contains a wrong value",
    0x0004: "the service in the mailbox protocol is not supported",
    0x0005: "mailbox protocol header is wrong",
    0x0006: "length of the received mailbox data is too short",
    0x0007: "mailbox protocol cannot be processed: not enough resources",
    0x0008: "length of the data is inconsistent",
}


def mailbox_error_text(code: int) -> str:
    return f"0x{code:04X} {MAILBOX_ERROR_TEXTS.get(code, 'unknown mailbox error')}"


# Emergency error codes: exact codes first, then the class given by the upper digits.
_EMERGENCY_EXACT: dict[int, str] = {
    0x0000: "error reset or no error",
    0x1000: "generic error",
    0x8110: "CAN overrun",
    0x8120: "error passive",
    0x8130: "life guard or heartbeat error",
    0x8140: "recovered from bus off",
    0x8700: "sync controller error",
    0xA000: "EtherCAT state machine: transition PREOP to SAFEOP failed",
    0xA001: "EtherCAT state machine: transition SAFEOP to OP failed",
}
_EMERGENCY_CLASSES: list[tuple[int, int, str]] = [
    (0xF000, 0x2000, "current"),
    (0xF000, 0x3000, "voltage"),
    (0xF000, 0x4000, "temperature"),
    (0xF000, 0x5000, "device hardware"),
    (0xF000, 0x6000, "device software"),
    (0xF000, 0x7000, "additional modules"),
    (0xFF00, 0x8100, "communication"),
    (0xFF00, 0x8200, "protocol error"),
    (0xFF00, 0x8300, "torque control"),
    (0xFF00, 0x8400, "velocity/speed control"),
    (0xFF00, 0x8500, "position control"),
    (0xFF00, 0x8600, "positioning control"),
    (0xFF00, 0x8700, "sync controller"),
    (0xF000, 0x8000, "monitoring"),
    (0xF000, 0x9000, "external error"),
    (0xF000, 0xA000, "EtherCAT state machine"),
    (0xFF00, 0xF000, "additional functions"),
    (0xFF00, 0xFF00, "device specific"),
]


def emergency_text(code: int) -> str:
    """Meaning of a CoE emergency error code (its class when the exact code is not listed)."""
    if code in _EMERGENCY_EXACT:
        return _EMERGENCY_EXACT[code]
    for mask, value, text in _EMERGENCY_CLASSES:
        if code & mask == value:
            return f"{text} error"
    return "unknown error"
