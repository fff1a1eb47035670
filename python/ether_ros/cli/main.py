"""Entry point of the ``ether-ros`` command.

Subcommand modules in ``ether_ros.cli`` define ``register(subparsers) -> None``; the parser each
registers must set ``func`` (``parser.set_defaults(func=...)``) to a callable taking the parsed
arguments and returning an exit code. User errors (:class:`EtherRosError`) become one line on
stderr and exit code 2; nothing the user typed is ever handed to a shell. A usage error names
the subcommand's own usage, not the top-level one. Output piped into a reader that stops early
(``ether-ros ... | head``) ends the command quietly instead of with a BrokenPipeError traceback.
"""

from __future__ import annotations

import argparse
import importlib
import os
import pkgutil
import sys
from collections.abc import Sequence
from typing import Any

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


# The exit status of a command whose reader went away (as if SIGPIPE had ended it: 128 + 13).
BROKEN_PIPE_EXIT = 141


def chosen_parser(parser: argparse.ArgumentParser, args: argparse.Namespace) -> Any:
    """The innermost (sub)command parser the arguments chose (``rt check`` -> its parser)."""
    while True:
        subs = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
        if not subs or getattr(args, subs[0].dest, None) is None:
            return parser
        parser = subs[0].choices[getattr(args, subs[0].dest)]


def main(argv: Sequence[str] | None = None) -> int:
    try:
        try:
            code = _run(argv)
        finally:  # a closed pipe shows here, not in the interpreter's exit
            sys.stdout.flush()
    except BrokenPipeError:  # the reader went away (`... | head`): end quietly
        _silence_stdout()
        return BROKEN_PIPE_EXIT
    return code


def _run(argv: Sequence[str] | None) -> int:
    parser = build_parser()
    args, extra = parser.parse_known_args(argv)
    if extra:  # the subcommand's usage, which names the options it does take
        chosen_parser(parser, args).error(f"unrecognized arguments: {' '.join(extra)}")
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


def _silence_stdout() -> None:
    """Point stdout at /dev/null so the interpreter's final flush does not fail again."""
    devnull = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(devnull, sys.stdout.fileno())
    finally:
        os.close(devnull)


if __name__ == "__main__":
    sys.exit(main())
