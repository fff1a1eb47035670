"""``ether-ros top``: live view of the slaves, loop timing, lost frames and DC sync error."""

from __future__ import annotations

import argparse
import sys
from typing import Any

from ether_ros.cli.common import add_interface_argument, add_parser, resolve_interface
from ether_ros.master.link import add_link_argument


def register(subparsers: Any) -> None:
    parser = add_parser(
        subparsers,
        "top",
        help="live view of a bus (standalone with --config, else the running node)",
        description="A full-screen live view: each slave's AL state, cycle counters, loop "
        "timing, DC sync error. Ctrl-P or F1: PANIC; q: quit. Reports older than two of the "
        "node's periods are marked stale. Needs a terminal.",
        examples=[
            "ether-ros top                                  # the running node (/diagnostics)",
            "ether-ros top --config config/laelaps.yaml -i eth1   # a bus of its own",
        ],
    )
    parser.add_argument("--config", help="bus configuration: open the bus in this process")
    add_interface_argument(parser, "network interface (with --config; overrides bus.interface)")
    add_link_argument(parser)
    parser.add_argument(
        "--topic",
        default="/diagnostics",
        help="diagnostics topic of the running node (default /diagnostics)",
    )
    parser.add_argument(
        "--interval", type=float, default=0.5, help="refresh period in seconds (default 0.5)"
    )
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from ether_ros.errors import EtherRosError
    from ether_ros.tools.live import (
        BusLiveSource,
        LiveSource,
        TopApp,
        run_top,
    )

    if args.interval <= 0:
        raise EtherRosError(f"--interval must be positive, got {args.interval}")
    if not (sys.stdin.isatty() and sys.stdout.isatty()):
        raise EtherRosError(
            "top is a full-screen view and needs a terminal on stdin and stdout; without one, "
            "'ether-ros console -c states -c stats' prints the same in text"
        )
    source: LiveSource
    if args.config:
        from ether_ros.master.bus import Bus
        from ether_ros.tools.session import load_config

        config = load_config(args.config, args.interface, args.link)
        interface = resolve_interface(args, config.bus.interface, "top", args.config)
        bus = Bus.open(config, interface=interface)
        try:
            bus.start()
        except BaseException:
            bus.close()
            raise
        source = BusLiveSource(bus)
    else:
        if args.interface:
            raise EtherRosError(
                "-i/--interface needs --config (a bus of its own); without them 'ether-ros top' "
                "shows the running node"
            )
        from ether_ros.ros.top_source import DiagnosticsLiveSource

        source = DiagnosticsLiveSource(args.topic)
    run_top(TopApp(source, interval=args.interval))
    return 0
