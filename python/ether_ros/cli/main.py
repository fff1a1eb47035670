"""Entry point of the ``ether-ros`` command.

Subcommand modules in ``ether_ros.cli`` define ``register(subparsers) -> None``; the parser each
registers must set ``func`` (``parser.set_defaults(func=...)``) to a callable taking the parsed
arguments and returning an exit code. User errors (:class:`EtherRosError`) become one line on
stderr and exit code 2; nothing the user typed is ever handed to a shell.
"""

from __future__ import annotations

import argparse
import importlib
import pkgutil
import sys
from collections.abc import Sequence

from ether_ros import __version__
from ether_ros.errors import EtherRosError

_NOT_COMMANDS = {"main", "common"}


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="ether-ros",
        description="Real-time EtherCAT master with a ROS 2 interface and a virtual EtherCAT bus.",
    )
    parser.add_argument("--version", action="version", version=f"ether-ros {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    import ether_ros.cli as package

    for info in sorted(pkgutil.iter_modules(package.__path__), key=lambda m: m.name):
        if info.name in _NOT_COMMANDS or info.name.startswith("_"):
            continue
        module = importlib.import_module(f"ether_ros.cli.{info.name}")
        register = getattr(module, "register", None)
        if register is not None:
            register(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    func = getattr(args, "func", None)
    if func is None:
        parser.print_help()
        return 2
    try:
        return int(func(args) or 0)
    except EtherRosError as exc:
        print(f"ether-ros {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())
