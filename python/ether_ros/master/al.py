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

from ether_ros._native.protocol import al, al_state_name, al_status_text, reg
from ether_ros.errors import AlStateRefused, AlStateTimeout, WorkingCounterError
from ether_ros.master.datagrams import Cmd, Datagram, DatagramService, fixed_address, u16


class AlState(IntEnum):
    INIT = al.INIT
    PREOP = al.PREOP
    BOOT = al.BOOT
    SAFEOP = al.SAFEOP
    OP = al.OP


_STATE_VALUES = frozenset(int(s) for s in AlState)


def state_name(state: int) -> str:
    return al_state_name(state & al.STATE_MASK) or f"UNKNOWN(0x{state & al.STATE_MASK:X})"


def al_code_text(code: int) -> str:
    """Words for an AL status code; vendor codes (0x8000+) and unknown codes say so."""
    return al_status_text(code)


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
        return cls(state=status & al.STATE_MASK, error=bool(status & al.ERROR), code=code)

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
            [Datagram(Cmd.FPRD, fixed_address(s.station, reg.AL_STATUS), 6) for s in slaves]
        )
        return [AlStatus.decode(r.data, r.wkc) for r in replies]

    def request(self, slaves: Sequence[SlaveRef], state: AlState, ack: bool = False) -> None:
        value = int(state) | (al.ERROR if ack else 0)
        replies = self.dg.batch(
            [
                Datagram(Cmd.FPWR, fixed_address(s.station, reg.AL_CONTROL), u16(value))
                for s in slaves
            ]
        )
        for slave, reply in zip(slaves, replies, strict=True):
            if reply.wkc != 1:
                raise WorkingCounterError(
                    f"requesting {state.name}", 1, reply.wkc, slave=str(slave)
                )

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
                    raise AlStateRefused(str(slave), int(state), status.state, status.code)
                if not status.answered or status.state != state:
                    pending.append((slave, status))
            if not pending:
                return
            if time.monotonic() > deadline:
                slave, status = pending[0]
                reached = status.state if status.answered else None
                raise AlStateTimeout(str(slave), int(state), reached, limit, status.describe())
            time.sleep(self.poll_interval_s)
