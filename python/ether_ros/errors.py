"""Errors the user sees. Every one says what is wrong and where; the CLI prints them as one line
and exits non-zero instead of showing a traceback."""

from __future__ import annotations


class EtherRosError(Exception):
    """Base class of all errors ether_ros reports to users."""


class ConfigError(EtherRosError):
    """Invalid bus configuration or ESI file: names the file, the key/element and the value."""


class BusError(EtherRosError):
    """The bus does not behave as configured: names the slave and the reason."""


class MailboxError(BusError):
    """A mailbox (CoE) exchange failed: names the slave, the object and the reason."""


class LinkError(EtherRosError):
    """The network link cannot be opened or used."""
