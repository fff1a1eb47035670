"""Errors the user sees. Every one says what is wrong and where; the CLI prints them as one line
and exits non-zero instead of showing a traceback.

Where an error comes from is data as well as text: a :class:`ConfigError` carries the file, the
line and the key path (``field``), a :class:`MessageError` the topic or service and the message
field, so tests and tools can check them without parsing the message.
"""

from __future__ import annotations

from pathlib import Path


class EtherRosError(Exception):
    """Base class of all errors ether_ros reports to users."""


class ConfigError(EtherRosError):
    """Invalid bus configuration or ESI file: names the file, the key/element and the value."""

    def __init__(
        self,
        message: str,
        *,
        file: str | Path | None = None,
        line: int | None = None,
        field: str | None = None,
    ) -> None:
        super().__init__(message)
        self.file = str(file) if file is not None else None
        self.line = line
        self.field = field


class MessageError(EtherRosError):
    """A ROS message or service request refused before anything was done: names the topic (or
    service) and the field when they are known."""

    def __init__(self, message: str, *, topic: str | None = None, field: str | None = None) -> None:
        super().__init__(message)
        self.topic = topic
        self.field = field


class BusError(EtherRosError):
    """The bus does not behave as configured: names the slave and the reason."""


class MailboxError(BusError):
    """A mailbox (CoE) exchange failed: names the slave, the object and the reason."""


class LinkError(EtherRosError):
    """The network link cannot be opened or used."""
