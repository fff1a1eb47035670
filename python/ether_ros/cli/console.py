"""``ether-ros console``: the operator console, a ROS 2 client of a running ether_ros node."""

from __future__ import annotations

import argparse
import shlex
import sys
from typing import Any

from ether_ros.cli.common import add_parser


def register(subparsers: Any) -> None:
    p = add_parser(
        subparsers,
        "console",
        help="operator console for a running ether_ros node (over ROS 2)",
        description="Operate a running ether_ros node over ROS 2: start/stop/restart, panic "
        "(Ctrl-P or F1), set variables (checked against the ESI types and ranges and the "
        "Laelaps leg workspace), states, statistics, SDO, sequence files. Without -c/--run "
        "and with a terminal it is interactive; otherwise it reads commands from stdin. On a "
        "terminal the keys work while commands run: Ctrl-P/F1 panic, Ctrl-C stops the "
        "running command (docs/console.md).",
        examples=[
            "ether-ros console",
            "ether-ros console -c states -c stats",
            'ether-ros console -c "set all y_cntr_traj1000=599" -c "set all b_ellipse100=4"',
            "ether-ros console --run lift.seq",
        ],
    )
    p.add_argument("--node", default="ether_comm", help="node name (default ether_comm)")
    p.add_argument("--namespace", default="", help="ROS namespace of the node")
    p.add_argument(
        "-c",
        "--command",
        action="append",
        default=[],
        metavar="LINE",
        help="run this console command and exit (repeatable, in order)",
    )
    p.add_argument("--run", metavar="FILE", help="run a sequence file and exit")
    p.add_argument(
        "--timeout", type=float, default=10.0, help="seconds to wait for the node (default 10)"
    )
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from ether_ros.console.app import Console, bounded_lines, run_lines
    from ether_ros.console.interactive import repl
    from ether_ros.ros.client import ClientError, EtherRosClient

    client = EtherRosClient(args.node, namespace=args.namespace)
    console: Console | None = None
    try:
        console = Console(client)
        try:
            state = client.wait_for_node(timeout=args.timeout)
        except ClientError:
            print(
                f"ether-ros console: no node {client.target} answers "
                f"(ROS_DOMAIN_ID and --node/--namespace must match the node's)",
                file=sys.stderr,
            )
            return 2
        if state in ("inactive", "active"):
            # The layout is latched; the commanded outputs come every snapshot period.
            try:
                client.layout(timeout=args.timeout)
                if state == "active":
                    client.wait_for(lambda latest: latest.commanded or latest.outputs, 2.0)
            except ClientError:
                pass
        lines = list(args.command)
        if args.run:
            lines.append(f"run {shlex.quote(args.run)}")
        console.panic_line.ready(timeout=2.0)  # discovered before a key may need it
        if sys.stdin.isatty() and sys.stdout.isatty():  # keys read while commands run
            return repl(console, lines=lines or None)
        if lines:
            return run_lines(console, lines)
        return run_lines(console, bounded_lines(sys.stdin.buffer))
    finally:
        if console is not None:
            console.close()
        client.close()
