"""What every ``ether-ros`` subcommand shares: how a parser is made (description and examples in
``--help``), the ``-i/--interface`` option, and the check that keeps EtherCAT frames off a
network the host uses.

An EtherCAT master and the simulator send raw Ethernet frames on the interface they open; on the
host's LAN card they would flood the office network (and the simulator would answer other
machines' broadcasts). An interface that carries an IPv4 address, or an IPv6 address beyond the
automatic link-local one, is taken to be such a network: commands refuse it unless
``--allow-ip-interface`` says the operator means it. A dedicated EtherCAT port, or a veth pair
made for the simulator, carries none.
"""

from __future__ import annotations

import argparse
import errno
import fcntl
import socket
import struct
from collections.abc import Sequence
from typing import Any

from ether_ros.errors import ConfigError

_SIOCGIFADDR = 0x8915  # linux/sockios.h: the interface's (first) IPv4 address
_IPV6_LINK_LOCAL_SCOPE = 0x20  # /proc/net/if_inet6 scope column (linux/ipv6.h IPV6_ADDR_LINKLOCAL)
_IF_INET6 = "/proc/net/if_inet6"


def add_parser(
    subparsers: Any,
    name: str,
    *,
    help: str,
    description: str,
    examples: Sequence[str],
    **kwargs: Any,
) -> argparse.ArgumentParser:
    """A subcommand's parser with ``description`` and an ``examples:`` section in its ``--help``
    (the text is printed as written, so examples keep their lines)."""
    epilog = "examples:\n" + "\n".join(f"  {line}" for line in examples)
    parser: argparse.ArgumentParser = subparsers.add_parser(
        name,
        help=help,
        description=description,
        epilog=epilog,
        formatter_class=argparse.RawDescriptionHelpFormatter,
        **kwargs,
    )
    return parser


def add_interface_argument(
    parser: argparse.ArgumentParser,
    help: str = "network interface (overrides bus.interface of the configuration)",
    *,
    required: bool = False,
    opens: bool = True,
) -> None:
    """``-i/--interface``; with ``opens`` (the command sends frames on it) also
    ``--allow-ip-interface``."""
    parser.add_argument("-i", "--interface", required=required, help=help)
    if opens:
        parser.add_argument(
            "--allow-ip-interface",
            action="store_true",
            help="use the interface even though it carries an IP address (refused by default: "
            "EtherCAT frames would go out on a network the host uses)",
        )


def interface_addresses(name: str) -> list[str]:
    """The IPv4 and non-link-local IPv6 addresses of interface ``name`` in this network
    namespace (empty when it has none, or does not exist: opening it will say so)."""
    found: list[str] = []
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        try:
            reply = fcntl.ioctl(s.fileno(), _SIOCGIFADDR, struct.pack("256s", name.encode()[:15]))
            found.append(socket.inet_ntoa(reply[20:24]))
        except OSError as exc:
            if exc.errno not in (errno.EADDRNOTAVAIL, errno.ENODEV, errno.EINVAL):
                raise
    try:
        with open(_IF_INET6) as f:
            lines = f.read().splitlines()
    except OSError:  # IPv6 disabled in this kernel
        lines = []
    for line in lines:
        fields = line.split()
        if len(fields) != 6 or fields[5] != name:
            continue
        if int(fields[3], 16) == _IPV6_LINK_LOCAL_SCOPE:
            continue
        raw = bytes.fromhex(fields[0])
        found.append(socket.inet_ntop(socket.AF_INET6, raw))
    return found


def check_interface(name: str, allow_ip: bool, command: str) -> None:
    """Refuse ``name`` when it carries an IP address, unless ``allow_ip``."""
    if allow_ip:
        return
    addresses = interface_addresses(name)
    if addresses:
        raise ConfigError(
            f"interface {name} carries IP address {', '.join(addresses)}: it looks like a "
            f"network the host uses, and EtherCAT frames would go out on it. Use a dedicated "
            f"port (or a veth pair for the simulator), or add --allow-ip-interface to "
            f"'ether-ros {command}' if you mean it"
        )


def resolve_interface(
    args: argparse.Namespace, configured: str | None, command: str, config: Any = None
) -> str:
    """The interface a command opens: ``-i`` or the configuration's ``bus.interface``;
    refused when neither names one, or when it carries an IP address (see the module)."""
    name = getattr(args, "interface", None) or configured
    if not name:
        where = f" and {config} sets no bus.interface" if config else ""
        raise ConfigError(f"no network interface: give 'ether-ros {command}' -i/--interface{where}")
    check_interface(name, bool(getattr(args, "allow_ip_interface", False)), command)
    return str(name)
