"""The error hierarchy (``ether_ros.errors``): codes travel as data, texts come from the protocol
crate, and a caller decides by class and fields, never by the message."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import pytest

from ether_ros import _native
from ether_ros.config.esi import load_esi
from ether_ros.errors import (
    BusError,
    ConfigError,
    FrameTimeout,
    LinkError,
    MailboxError,
    MailboxTimeout,
    SdoAbort,
    WorkingCounterError,
)
from ether_ros.master.datagrams import DatagramService


class Silent:
    """A transport whose datagrams reach no slave (working counter 0)."""

    def transact(
        self, datagrams: Sequence[tuple[int, int, bytes | int]], timeout_us: int = 0,
        retries: int = 0,
    ) -> list[tuple[bytes, int]]:  # fmt: skip
        return [(bytes(p if isinstance(p, int) else len(p)), 0) for _c, _a, p in datagrams]


class TimesOut:
    def transact(self, *args: object, **kwargs: object) -> list[tuple[bytes, int]]:
        raise TimeoutError("no frame came back")


def test_working_counter_is_data() -> None:
    dg = DatagramService(Silent())  # type: ignore[arg-type]
    with pytest.raises(WorkingCounterError) as err:
        dg.write_checked(0x1001, 0x0120, b"\x02\x00", "AL control", "slave 0 (a)")
    assert (err.value.expected, err.value.received, err.value.slave) == (1, 0, "slave 0 (a)")
    assert isinstance(err.value, BusError)
    assert str(err.value) == "slave 0 (a): writing AL control (0x0120) got no answer (wkc 0)"


def test_a_transport_timeout_is_a_frame_timeout_with_its_frame() -> None:
    dg = DatagramService(TimesOut(), retries=2)  # type: ignore[arg-type]
    with pytest.raises(FrameTimeout) as err:
        dg.fprd(0x1001, 0x0130, 2)
    assert (err.value.commands, err.value.attempts) == (("FPRD",), 3)
    assert isinstance(err.value, LinkError)


def test_context_is_added_without_touching_the_reason() -> None:
    timeout = MailboxTimeout("leg", 0.5, "a CoE reply in the read mailbox")
    framed = timeout.in_context("SDO upload 0x1018:01")
    assert isinstance(framed, MailboxTimeout) and framed.timeout_s == 0.5
    assert framed.reason == timeout.reason and framed.context == "SDO upload 0x1018:01"
    assert str(framed) == (
        "slave 'leg': SDO upload 0x1018:01 failed: timed out after 0.5 s waiting for a CoE "
        "reply in the read mailbox"
    )
    abort = SdoAbort("leg", 0x1018, 1, 0x06090011, context="SDO upload 0x1018:01")
    assert str(abort).endswith("aborted: 0x06090011 subindex does not exist")
    assert isinstance(abort, MailboxError) and abort.code == 0x06090011


def test_engine_errors_belong_to_the_hierarchy() -> None:
    assert issubclass(_native.EngineError, LinkError)
    assert issubclass(_native.EngineTimeout, FrameTimeout)
    engine = _native.Engine.open_sim(_native.SimNetwork())
    engine.close()
    with pytest.raises(_native.EngineError, match="closed"):
        engine.transact([("BRD", 0, 2)])


def test_esi_errors_carry_file_line_and_element(tmp_path: Path) -> None:
    bad = tmp_path / "bad.xml"
    bad.write_text(
        '<?xml version="1.0"?>\n<EtherCATInfo><Vendor><Id>#xZZ</Id></Vendor>'
        "<Descriptions><Devices/></Descriptions></EtherCATInfo>\n"
    )
    with pytest.raises(ConfigError) as err:
        load_esi(bad)
    assert err.value.file == str(bad)
    assert err.value.line == 2 and err.value.field == "<Id>"
