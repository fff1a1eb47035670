"""The ``error``/``code`` fields of the node's service answers come from the typed errors'
data (ether_ros.errors), found through a chain of causes."""

from __future__ import annotations

from types import SimpleNamespace

from ether_ros._native import protocol
from ether_ros.errors import AlStateRefused, BusError, EtherRosError, MailboxErrorReply, SdoAbort
from ether_ros.ros.error_fields import error_fields, fill


def test_each_coded_error_answers_its_code() -> None:
    abort = SdoAbort("leg", 0x5FFF, 0, protocol.sdo_abort.ABORT_NO_OBJECT)
    assert error_fields(abort) == ("SdoAbort", 0x06020000)
    refused = AlStateRefused("leg", 8, 4, protocol.al_code.SYNCHRONIZATION_ERROR)
    assert error_fields(refused) == ("AlStateRefused", 0x001A)
    assert error_fields(MailboxErrorReply("leg", 0x0002)) == ("MailboxErrorReply", 2)


def test_an_error_raised_from_a_coded_one_answers_the_cause() -> None:
    try:
        try:
            raise AlStateRefused("leg", 8, 4, 0x001D)
        except AlStateRefused as exc:
            raise BusError("bring-up failed") from exc
    except BusError as exc:
        assert error_fields(exc) == ("AlStateRefused", 0x001D)


def test_no_code_and_no_error() -> None:
    assert error_fields(EtherRosError("no such slave")) == ("EtherRosError", 0)
    assert error_fields(ValueError("x")) == ("ValueError", 0)
    assert error_fields(None) == ("", 0)
    resp = fill(SimpleNamespace(error="?", code=7), None)
    assert (resp.error, resp.code) == ("", 0)
