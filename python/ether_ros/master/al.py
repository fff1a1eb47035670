"""Application-layer (AL) state machine of the slaves, seen from the master.

The master requests a state by writing AL control (0x0120) and watches AL status (0x0130): the
low nibble is the state reached, bit 4 says the slave refused or left a state and put the reason
into the AL status code (0x0134). A refusal is acknowledged by writing the current state with
bit 4 set. Every error names the slave and explains the code in words.
"""

from __future__ import annotations

import struct
import time
from collections.abc import Sequence
from dataclasses import dataclass
from enum import IntEnum

from ether_ros.errors import BusError
from ether_ros.master.datagrams import Cmd, Datagram, DatagramService, fixed_address, u16

AL_CONTROL = 0x0120
AL_STATUS = 0x0130
AL_STATUS_CODE = 0x0134
ERROR_FLAG = 0x10


class AlState(IntEnum):
    INIT = 0x01
    PREOP = 0x02
    BOOT = 0x03
    SAFEOP = 0x04
    OP = 0x08


_STATE_VALUES = frozenset(int(s) for s in AlState)


def state_name(state: int) -> str:
    try:
        return AlState(state & 0x0F).name
    except ValueError:
        return f"UNKNOWN(0x{state & 0x0F:X})"


# ETG.1000.6 AL status codes, explained in our own words.
AL_CODE_TEXT: dict[int, str] = {
    0x0000: "no error",
    0x0001: "unspecified error",
    0x0002: "no memory",
    0x0003: "invalid device setup",
    0x0011: "invalid requested state change",
    0x0012: "unknown requested state",
    0x0013: "bootstrap state not supported",
    0x0014: "no valid firmware",
    0x0015: "invalid mailbox configuration (bootstrap)",
    0x0016: "invalid mailbox configuration",
    0x0017: "invalid SyncManager configuration",
    0x0018: "no valid inputs available",
    0x0019: "no valid outputs",
    0x001A: "synchronization error",
    0x001B: "SyncManager watchdog expired (no process data from the master)",
    0x001C: "invalid SyncManager types",
    0x001D: "invalid output configuration",
    0x001E: "invalid input configuration",
    0x001F: "invalid watchdog configuration",
    0x0020: "slave needs a cold start",
    0x0021: "slave needs INIT",
    0x0022: "slave needs PREOP",
    0x0023: "slave needs SAFEOP",
    0x0024: "invalid input mapping",
    0x0025: "invalid output mapping",
    0x0026: "inconsistent settings",
    0x0027: "free-run mode not supported",
    0x0028: "synchronization mode not supported",
    0x0029: "free-run needs 3-buffer mode",
    0x002A: "background watchdog",
    0x002B: "no valid inputs and outputs",
    0x002C: "fatal synchronization error",
    0x002D: "no SYNC error",
    0x002E: "cycle time too small",
    0x0030: "invalid DC SYNC configuration",
    0x0031: "invalid DC latch configuration",
    0x0032: "PLL error (DC not locked)",
    0x0033: "DC SYNC I/O error",
    0x0034: "DC SYNC timeout",
    0x0035: "invalid DC SYNC cycle time",
    0x0036: "DC SYNC0 cycle time does not fit the application",
    0x0037: "DC SYNC1 cycle time does not fit the application",
    0x0041: "mailbox error (AoE)",
    0x0042: "mailbox error (EoE)",
    0x0043: "mailbox error (CoE)",
    0x0044: "mailbox error (FoE)",
    0x0045: "mailbox error (SoE)",
    0x004F: "mailbox error (VoE)",
    0x0050: "EEPROM not accessible",
    0x0051: "EEPROM error",
    0x0052: "external hardware not ready",
    0x0060: "slave restarted locally",
    0x0061: "device identification value updated",
    0x0070: "detected module ident list does not match",
    0x00F0: "application controller not available",
}


def al_code_text(code: int) -> str:
    """Words for an AL status code; vendor codes (0x8000+) and unknown codes say so."""
    if code in AL_CODE_TEXT:
        return AL_CODE_TEXT[code]
    if code >= 0x8000:
        return f"vendor-specific error 0x{code:04X}"
    return f"unknown AL status code 0x{code:04X}"


# How long each requested state may take before the master gives up (seconds). SAFEOP and OP
# include the slave's own checks (process data, DC lock), which real devices take time for.
TRANSITION_TIMEOUT_S: dict[AlState, float] = {
    AlState.INIT: 5.0,
    AlState.PREOP: 3.0,
    AlState.BOOT: 3.0,
    AlState.SAFEOP: 10.0,
    AlState.OP: 10.0,
}


@dataclass(frozen=True)
class AlStatus:
    """A slave's AL status: state reached, error flag and status code."""

    state: int
    error: bool
    code: int
    answered: bool = True

    @classmethod
    def decode(cls, data: bytes, wkc: int) -> AlStatus:
        if wkc < 1 or len(data) < 6:
            return cls(state=0, error=False, code=0, answered=False)
        status, _reserved, code = struct.unpack_from("<HHH", data)
        return cls(state=status & 0x0F, error=bool(status & ERROR_FLAG), code=code)

    @property
    def name(self) -> str:
        return state_name(self.state) if self.answered else "NO ANSWER"

    def describe(self) -> str:
        if not self.answered:
            return "does not answer"
        text = self.name
        if self.error:
            text += f" + ERROR 0x{self.code:04X} ({al_code_text(self.code)})"
        return text


@dataclass(frozen=True)
class SlaveRef:
    """How AL errors name a slave: its position, station address and configured name."""

    position: int
    station: int
    name: str

    def __str__(self) -> str:
        return f"slave {self.position} ({self.name})"


class AlStateMachine:
    """Request and wait for AL states on a group of slaves (all in one frame per poll)."""

    def __init__(self, dg: DatagramService, poll_interval_s: float = 0.002) -> None:
        self.dg = dg
        self.poll_interval_s = poll_interval_s

    def read(self, slaves: Sequence[SlaveRef]) -> list[AlStatus]:
        replies = self.dg.batch(
            [Datagram(Cmd.FPRD, fixed_address(s.station, AL_STATUS), 6) for s in slaves]
        )
        return [AlStatus.decode(r.data, r.wkc) for r in replies]

    def request(self, slaves: Sequence[SlaveRef], state: AlState, ack: bool = False) -> None:
        value = int(state) | (ERROR_FLAG if ack else 0)
        replies = self.dg.batch(
            [Datagram(Cmd.FPWR, fixed_address(s.station, AL_CONTROL), u16(value)) for s in slaves]
        )
        for slave, reply in zip(slaves, replies, strict=True):
            if reply.wkc != 1:
                raise BusError(f"{slave}: no answer when requesting {state.name}")

    def acknowledge(self, slave: SlaveRef, status: AlStatus) -> None:
        """Acknowledge an error indication by requesting the current state with bit 4 set."""
        state = status.state if status.state in _STATE_VALUES else AlState.INIT
        self.request([slave], AlState(state), ack=True)

    def transition(
        self, slaves: Sequence[SlaveRef], state: AlState, timeout_s: float | None = None
    ) -> None:
        """Bring every slave to ``state``; on refusal acknowledge and raise naming the reason."""
        if not slaves:
            return
        # Acknowledge errors left over from before so the new request is not ignored.
        for slave, status in zip(slaves, self.read(slaves), strict=True):
            if status.answered and status.error:
                self.acknowledge(slave, status)
        self.request(slaves, state)
        self.wait(slaves, state, timeout_s)

    def wait(
        self, slaves: Sequence[SlaveRef], state: AlState, timeout_s: float | None = None
    ) -> None:
        limit = TRANSITION_TIMEOUT_S[state] if timeout_s is None else timeout_s
        deadline = time.monotonic() + limit
        while True:
            statuses = self.read(slaves)
            pending: list[tuple[SlaveRef, AlStatus]] = []
            for slave, status in zip(slaves, statuses, strict=True):
                if status.answered and status.error:
                    self.acknowledge(slave, status)
                    raise BusError(
                        f"{slave} refused {state.name}: stays in {status.name}, "
                        f"AL status code 0x{status.code:04X} ({al_code_text(status.code)})"
                    )
                if not status.answered or status.state != state:
                    pending.append((slave, status))
            if not pending:
                return
            if time.monotonic() > deadline:
                slave, status = pending[0]
                raise BusError(
                    f"{slave} did not reach {state.name} within {limit:g} s "
                    f"(AL status: {status.describe()})"
                )
            time.sleep(self.poll_interval_s)
