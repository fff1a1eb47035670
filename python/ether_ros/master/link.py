"""Opening the engine on a network interface through the link the configuration asks for.

``packet`` is an AF_PACKET raw socket (any interface, CAP_NET_RAW). ``xdp`` is an AF_XDP socket
with an XDP program that steers EtherCAT frames past the kernel's stack (a driver with native
XDP; CAP_NET_RAW, CAP_NET_ADMIN and CAP_BPF). ``auto`` tries ``xdp`` and falls back to
``packet``, logging why in one line. See docs/engine.md.
"""

from __future__ import annotations

import argparse
import logging
from typing import Any

from ether_ros.errors import EtherRosError, LinkError

LINKS = ("packet", "xdp", "auto")

log = logging.getLogger(__name__)


def open_engine(
    interface: str, link: str = "packet", busy_poll_us: int = 0, qdisc_bypass: bool = True
) -> Any:
    """An ``ether_ros._native.Engine`` on ``interface`` through ``link`` (one of ``LINKS``).
    ``qdisc_bypass`` False (``bus.capture``): AF_PACKET frames take the kernel's transmit queue,
    so tcpdump/tshark on ``interface`` see them (AF_XDP frames never pass the stack)."""
    from ether_ros import _native

    if link not in LINKS:
        raise LinkError(f"unknown link {link!r}: use one of {', '.join(LINKS)}")
    if link == "auto":
        try:
            return _native.Engine.open_interface(interface, "xdp", busy_poll_us, qdisc_bypass)
        except (EtherRosError, OSError) as exc:
            log.warning("link auto: no AF_XDP on %s (%s); using AF_PACKET", interface, exc)
            link = "packet"
    try:
        return _native.Engine.open_interface(interface, link, busy_poll_us, qdisc_bypass)
    except EtherRosError:
        raise
    except OSError as exc:
        raise LinkError(f"cannot open interface {interface}: {exc}") from None


def add_link_argument(parser: argparse.ArgumentParser) -> None:
    """``--link packet|xdp|auto`` for a command that opens an interface."""
    parser.add_argument(
        "--link",
        choices=LINKS,
        help="how frames reach the interface: AF_PACKET, AF_XDP, or AF_XDP when available"
        " (overrides bus.link; default packet)",
    )
