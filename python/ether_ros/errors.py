"""Errors the user sees. Every one says what is wrong and where; the CLI prints them as one line
and exits non-zero instead of showing a traceback.

One hierarchy for the Python side and the Rust core. Every class is defined here, once: the
Rust extension raises these classes (``crates/py`` imports them from this module) and
re-exports the engine's as ``ether_ros._native.EngineError`` and ``EngineTimeout``. Errors that
have codes carry them as attributes — an AL status code, an SDO abort code, a working counter —
and render their text from the protocol crate (``ether_ros._native.protocol``), so a caller
decides by the data, never by parsing a message::

    EtherRosError
    ├── ConfigError (file, line, field, value)
    ├── MessageError (topic, field)
    ├── InvalidRequest (field, code; also a ValueError): an argument the Rust core refused
    ├── BusError (slave)
    │   ├── AlStateRefused (slave, state, reached, code)
    │   ├── AlStateTimeout (slave, state, reached, timeout_s)
    │   ├── WorkingCounterError (expected, received, what)
    │   ├── IdentityMismatch (expected, found)
    │   ├── SiiReadError (word, status)
    │   └── MailboxError (slave name, context)
    │       ├── MailboxTimeout (timeout_s, waiting_for)
    │       ├── MailboxErrorReply (code)
    │       └── SdoAbort (index, subindex, code)
    └── LinkError (errno)
        ├── FrameTimeout (commands, attempts, timeout_us, link)
        └── EngineError: the engine cannot do what was asked
            └── EngineTimeout (also a FrameTimeout)

Where an error comes from is data as well as text: a :class:`ConfigError` carries the file, the
line and the key path (``field``), a :class:`MessageError` the topic or service and the message
field, so tests and tools can check them without parsing the message.
"""

from __future__ import annotations

import copy
from pathlib import Path
from types import ModuleType
from typing import Any


class EtherRosError(Exception):
    """Base class of all errors ether_ros reports to users."""

    def __reduce__(self) -> tuple[Any, ...]:
        # Rebuilt from the text and the fields, not by calling __init__ again (the subclasses'
        # constructors take data, not the text): copy and pickle keep class and data.
        return (_restore, (type(self), self.args, dict(self.__dict__)))


def _restore(cls: type[EtherRosError], args: tuple[Any, ...], state: dict[str, Any]) -> Any:
    error = cls.__new__(cls)
    error.args = args
    error.__dict__.update(state)
    return error


class ConfigError(EtherRosError):
    """Invalid bus configuration or ESI file: names the file, the line, the key/element and the
    value, which it also carries as ``file``, ``line``, ``field`` and ``value`` (None where
    unknown)."""

    def __init__(
        self,
        message: str,
        *,
        file: str | Path | None = None,
        line: int | None = None,
        field: str | None = None,
        value: Any = None,
    ) -> None:
        super().__init__(message)
        self.file = str(file) if file is not None else None
        self.line = line
        self.field = field
        self.value = value


class MessageError(EtherRosError):
    """A ROS message or service request refused before anything was done: names the topic (or
    service) and the field when they are known."""

    def __init__(self, message: str, *, topic: str | None = None, field: str | None = None) -> None:
        super().__init__(message)
        self.topic = topic
        self.field = field


class BusError(EtherRosError):
    """The bus does not behave as configured: names the slave and the reason.

    ``slave`` names the slave (None when the error concerns no single one), ``reason`` is the
    text without it; ``str()`` reads ``"<slave>: <reason>"``."""

    def __init__(self, reason: str, *, slave: str | None = None) -> None:
        self.slave = slave
        self.reason = reason
        super().__init__(self._text())

    def _text(self) -> str:
        return f"{self.slave}: {self.reason}" if self.slave else self.reason


class AlStateRefused(BusError):
    """A slave refused a requested AL state: ``state`` requested, ``reached`` the state it
    stays in, ``code`` its AL status code (register 0x0134)."""

    def __init__(self, slave: str, state: int, reached: int, code: int) -> None:
        self.state = state
        self.reached = reached
        self.code = code
        super().__init__(
            f"refused {_state(state)}: stays in {_state(reached)}, AL status code "
            f"0x{code:04X} ({_protocol().al_status_text(code)})",
            slave=slave,
        )

    def _text(self) -> str:
        return f"{self.slave} {self.reason}"


class AlStateTimeout(BusError):
    """A slave did not reach ``state`` within ``timeout_s``; ``reached`` is the state it showed
    last (None when it did not answer), ``status`` its AL status in words."""

    def __init__(
        self, slave: str, state: int, reached: int | None, timeout_s: float, status: str
    ) -> None:
        self.state = state
        self.reached = reached
        self.timeout_s = timeout_s
        super().__init__(
            f"did not reach {_state(state)} within {timeout_s:g} s (AL status: {status})",
            slave=slave,
        )

    def _text(self) -> str:
        return f"{self.slave} {self.reason}"


class WorkingCounterError(BusError):
    """A datagram came back with the wrong working counter: ``expected`` and ``received``;
    ``what`` names the access."""

    def __init__(
        self, what: str, expected: int, received: int, *, slave: str | None = None
    ) -> None:
        self.what = what
        self.expected = expected
        self.received = received
        super().__init__(f"{what} got no answer (wkc {received})", slave=slave)


class IdentityMismatch(BusError):
    """A slave is not the device the configuration names: ``expected`` and ``found`` are
    (vendor id, product code, revision); an expected revision of None is not checked."""

    def __init__(
        self,
        slave: str,
        expected: tuple[int, int, int | None],
        found: tuple[int, int, int],
    ) -> None:
        self.expected = expected
        self.found = found
        want = f"vendor 0x{expected[0]:08X} product 0x{expected[1]:08X}"
        if expected[2] is not None:
            want += f" revision 0x{expected[2]:08X}"
        have = f"vendor 0x{found[0]:08X} product 0x{found[1]:08X} revision 0x{found[2]:08X}"
        super().__init__(f"expected {want}, found {have}", slave=slave)


class SiiReadError(BusError):
    """Reading the SII EEPROM failed at ``word``: ``status`` is the EEPROM control/status
    register (0x0502) with the error bits the ESC set."""

    def __init__(self, slave: str, word: int, status: int) -> None:
        self.word = word
        self.status = status
        super().__init__(
            f"SII read at word 0x{word:04X} failed (EEPROM control 0x{status:04X})", slave=slave
        )


class MailboxError(BusError):
    """A mailbox (CoE) exchange with ``slave`` (its name) failed: names the slave, the object
    and the reason.

    ``context`` says what the exchange was for (``SDO upload 0x1018:01``); ``in_context``
    returns the same error for a given context, so a caller adds it without touching the
    text. ``verb`` is how the context reads (``failed``, ``aborted``)."""

    def __init__(
        self, reason: str, *, slave: str | None = None, context: str = "", verb: str = "failed"
    ) -> None:
        self.context = context
        self.verb = verb
        super().__init__(reason, slave=slave)

    def _text(self) -> str:
        text = f"{self.context} {self.verb}: {self.reason}" if self.context else self.reason
        return f"slave '{self.slave}': {text}" if self.slave else text

    def in_context(self, context: str) -> MailboxError:
        """This error (same class, same data) for the exchange ``context``."""
        clone = copy.copy(self)
        clone.context = context
        clone.args = (clone._text(),)
        return clone


class MailboxTimeout(MailboxError):
    """No mailbox answer within ``timeout_s``; ``waiting_for`` says for what."""

    def __init__(self, slave: str | None, timeout_s: float, waiting_for: str) -> None:
        self.timeout_s = timeout_s
        self.waiting_for = waiting_for
        super().__init__(f"timed out after {timeout_s:g} s waiting for {waiting_for}", slave=slave)


class MailboxErrorReply(MailboxError):
    """The slave answered with a mailbox error (type 0): ``code`` (ETG.1000.4 table 30)."""

    def __init__(self, slave: str | None, code: int) -> None:
        self.code = code
        super().__init__(
            f"mailbox error 0x{code:04X} {_protocol().mailbox_error_text(code)}", slave=slave
        )


class SdoAbort(MailboxError):
    """The slave aborted an SDO transfer or information request: ``index``, ``subindex`` and the
    abort ``code`` (ETG.1000.6 / CiA 301), its text from the protocol crate."""

    def __init__(
        self,
        slave: str | None,
        index: int,
        subindex: int,
        code: int,
        *,
        context: str = "",
        verb: str = "aborted",
    ) -> None:
        self.index = index
        self.subindex = subindex
        self.code = code
        super().__init__(
            f"0x{code:08X} {_protocol().sdo_abort_text(code)}",
            slave=slave,
            context=context,
            verb=verb,
        )


class LinkError(EtherRosError):
    """The network link cannot be opened or used; ``errno`` is the OS error code if any."""

    errno: int | None = None


class FrameTimeout(LinkError):
    """No reply to a frame within its retries: the frame's ``commands``, ``attempts`` and the
    wait per attempt ``timeout_us`` on ``link``."""

    commands: tuple[str, ...] = ()
    attempts: int = 0
    timeout_us: int = 0
    link: str = ""


class InvalidRequest(EtherRosError, ValueError):
    """The Rust core (engine, simulator) refused an argument before doing anything: the text
    says what is wrong. A ``ValueError`` as well, so a caller that checks its input that way
    keeps working.

    The simulator's refusals carry the refused ``field`` (``"SlaveSpec.pdram_kib"``,
    ``"Drop.rate"``, ``"SlaveSpec.device"``, ``"slave"`` for a position argument) and a
    ``code`` saying why, one of the ``*`` constants below; both are None where the core gives
    no more than the text (the engine's refusals today)."""

    field: str | None = None
    code: str | None = None

    #: A number outside the range its field allows.
    OUT_OF_RANGE = "out_of_range"
    #: A value of the right type that the field does not allow (an unknown name, a bad form).
    BAD_VALUE = "bad_value"
    #: No slave at the position given.
    NO_SLAVE = "no_slave"
    #: The slave has no object dictionary entry at the index and subindex given.
    NO_ENTRY = "no_entry"
    #: Nothing is connected to the port given.
    NOT_CONNECTED = "not_connected"
    #: The simulator already serves an interface.
    BUSY = "busy"
    #: The simulator cannot build what the spec describes (device model, topology, chip).
    REFUSED = "refused"


class EngineError(LinkError):
    """The engine cannot do what was asked: link failure, wrong state, or the real-time setup
    was refused. Raised by ``ether_ros._native.Engine`` (and re-exported there)."""


class EngineTimeout(EngineError, FrameTimeout):
    """No reply to an acyclic frame within its retries: the frame's ``commands``, the
    ``attempts`` and the wait per attempt ``timeout_us`` on ``link``."""


def _protocol() -> ModuleType:
    # Imported late: the extension imports this module while it loads (its exception classes
    # derive from these), so this module cannot import the extension at its top.
    from ether_ros._native import protocol

    return protocol


def _state(value: int) -> str:
    return _protocol().al_state_name(value) or f"UNKNOWN(0x{value & 0x0F:X})"
