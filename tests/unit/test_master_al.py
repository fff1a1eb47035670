"""AL status decoding, code texts, and the state machine's waits against a scripted slave."""

from __future__ import annotations

import struct
from collections.abc import Sequence

import pytest

from ether_ros._native.protocol import reg
from ether_ros.errors import AlStateRefused, AlStateTimeout
from ether_ros.master.al import (
    AlState,
    AlStateMachine,
    AlStatus,
    SlaveRef,
    al_code_text,
)
from ether_ros.master.datagrams import Cmd, DatagramService


def test_code_texts() -> None:
    assert al_code_text(0x001B).startswith("SyncManager watchdog")
    assert al_code_text(0x0011) == "invalid requested state change"
    assert al_code_text(0x8001) == "vendor-specific error 0x8001"
    assert al_code_text(0x00EE) == "unknown AL status code 0x00EE"


def test_status_decode() -> None:
    st = AlStatus.decode(struct.pack("<HHH", 0x14, 0, 0x001D), 1)
    assert st.state == AlState.SAFEOP and st.error and st.code == 0x1D
    assert st.describe() == "SAFEOP + ERROR 0x001D (invalid output configuration)"
    assert not AlStatus.decode(b"", 0).answered
    assert AlStatus.decode(b"\0" * 6, 0).describe() == "does not answer"


class ScriptedSlave:
    """One slave behind a fake engine: follows AL control, or refuses a state with a code."""

    def __init__(self, refuse: int | None = None, code: int = 0) -> None:
        self.state = AlState.INIT
        self.error = False
        self.code = 0
        self.refuse = refuse
        self.refuse_code = code
        self.writes: list[int] = []

    def transact(
        self, datagrams: Sequence[tuple[int, int, bytes | int]], timeout_us: int = 0,
        retries: int = 0,
    ) -> list[tuple[bytes, int]]:  # fmt: skip
        out = []
        for cmd, address, payload in datagrams:
            ado = address >> 16
            if cmd == Cmd.FPWR and ado == reg.AL_CONTROL:
                assert isinstance(payload, bytes)
                value = struct.unpack("<H", payload)[0]
                self.writes.append(value)
                if value & 0x10:
                    self.error = False
                requested = value & 0x0F
                if requested == self.refuse:
                    self.error, self.code = True, self.refuse_code
                else:
                    self.state = AlState(requested)
                out.append((payload, 1))
            elif cmd == Cmd.FPRD and ado == reg.AL_STATUS:
                status = self.state | (0x10 if self.error else 0)
                out.append((struct.pack("<HHH", status, 0, self.code), 1))
            else:
                raise AssertionError(f"unexpected datagram {cmd} {address:#x}")
        return out


REF = SlaveRef(2, 0x1003, "front_left_leg")


def test_transition_reaches_state() -> None:
    slave = ScriptedSlave()
    al = AlStateMachine(DatagramService(slave), poll_interval_s=0)
    al.transition([REF], AlState.PREOP, timeout_s=1)
    assert slave.state == AlState.PREOP


def test_refusal_is_acknowledged_and_explained() -> None:
    slave = ScriptedSlave(refuse=AlState.OP, code=0x001D)
    slave.state = AlState.SAFEOP
    al = AlStateMachine(DatagramService(slave), poll_interval_s=0)
    with pytest.raises(AlStateRefused) as err:
        al.transition([REF], AlState.OP, timeout_s=1)
    # The codes as data: what was asked, where the slave stays, and why.
    assert (err.value.state, err.value.reached, err.value.code) == (
        AlState.OP,
        AlState.SAFEOP,
        0x1D,
    )
    assert err.value.slave == str(REF)
    msg = str(err.value)
    assert "slave 2 (front_left_leg) refused OP" in msg
    assert "0x001D (invalid output configuration)" in msg
    # the error was acknowledged (current state with bit 4)
    assert slave.writes[-1] == AlState.SAFEOP | 0x10
    assert not slave.error


def test_timeout_names_the_slave() -> None:
    class Stuck(ScriptedSlave):
        def transact(self, datagrams, timeout_us=0, retries=0):  # type: ignore[no-untyped-def]
            replies = super().transact(datagrams, timeout_us, retries)
            self.state = AlState.INIT  # never gets anywhere
            return replies

    al = AlStateMachine(DatagramService(Stuck()), poll_interval_s=0)
    with pytest.raises(
        AlStateTimeout, match=r"slave 2 \(front_left_leg\) did not reach SAFEOP"
    ) as err:
        al.transition([REF], AlState.SAFEOP, timeout_s=0.05)
    assert (err.value.state, err.value.reached, err.value.timeout_s) == (
        AlState.SAFEOP, AlState.INIT, 0.05
    )  # fmt: skip
