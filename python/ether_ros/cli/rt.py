"""``ether-ros rt check`` and ``ether-ros rt setup``: the real-time host."""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

from ether_ros.cli.common import add_interface_argument, add_parser
from ether_ros.tools.host import Host, HostError
from ether_ros.tools.rt_check import FAIL, CheckOptions, format_table, run_checks
from ether_ros.tools.rt_setup import apply_plan, make_plan, undo

DEFAULT_UNDO_FILE = "ether-ros-rt-undo.json"


def register(subparsers: Any) -> None:
    rt = add_parser(
        subparsers,
        "rt",
        help="check or prepare this host for real-time operation",
        description="Check (rt check) or change (rt setup) the host's real-time tuning: kernel, "
        "CPU isolation and frequency, the NIC's interrupts and coalescing (docs/realtime.md).",
        examples=["ether-ros rt check -i eth1 --cpu 3", "ether-ros rt setup -i eth1 --cpu 3"],
    )
    sub = rt.add_subparsers(dest="rt_command", metavar="ACTION", required=True)

    check = add_parser(
        sub,
        "check",
        help="pass/warn/fail table of the host's real-time tuning",
        description="Inspect the host (read-only) and print a pass/warn/fail table of what "
        "matters for the RT thread; the exit status is 1 when a check fails.",
        examples=["ether-ros rt check", "ether-ros rt check -i eth1 --cpu 3 --json"],
    )
    check.add_argument("--root", default="/", help="host root to inspect (default /)")
    add_interface_argument(check, "the EtherCAT network interface", opens=False)
    check.add_argument("--cpu", type=int, help="the CPU the RT thread runs on")
    check.add_argument(
        "--priority",
        type=int,
        default=80,
        help="the RT thread's priority (bus config realtime.priority, default 80)",
    )
    check.add_argument(
        "--policy",
        choices=("fifo", "deadline", "other"),
        default="fifo",
        help="the RT thread's policy (bus config realtime.policy)",
    )
    check.add_argument("--json", action="store_true", help="print JSON instead of a table")
    check.set_defaults(func=run_check)

    setup = add_parser(
        sub,
        "setup",
        help="apply the runtime tuning (dry run unless --apply)",
        description="Plan the runtime tuning for an RT thread on --cpu driving --interface "
        "(IRQ affinity and priority, coalescing, CPU frequency); print it, or make it with "
        "--apply, recording the previous values so --undo can restore them.",
        examples=[
            "ether-ros rt setup -i eth1 --cpu 3",
            "ether-ros rt setup -i eth1 --cpu 3 --apply",
            "ether-ros rt setup --undo ether-ros-rt-undo.json",
        ],
    )
    setup.add_argument("--root", default="/", help="host root to change (default /)")
    setup.add_argument("--cpu", type=int, help="the CPU to dedicate to the RT thread")
    add_interface_argument(setup, "the EtherCAT network interface", opens=False)
    setup.add_argument(
        "--priority",
        type=int,
        default=80,
        help="the RT thread's priority: NIC IRQ threads go above it (default 80)",
    )
    setup.add_argument("--apply", action="store_true", help="make the changes")
    setup.add_argument(
        "--undo-file",
        default=DEFAULT_UNDO_FILE,
        help=f"where --apply records previous values (default {DEFAULT_UNDO_FILE})",
    )
    setup.add_argument("--undo", metavar="FILE", help="restore what an earlier --apply changed")
    setup.set_defaults(func=run_setup)


def run_check(args: argparse.Namespace) -> int:
    host = Host(args.root)
    options = CheckOptions(
        interface=args.interface, cpu=args.cpu, priority=args.priority, policy=args.policy
    )
    report = run_checks(host, options)
    if args.json:
        print(json.dumps(report.as_dict(), indent=2))
    else:
        print(format_table(report))
    return 1 if report.worst == FAIL else 0


def run_setup(args: argparse.Namespace) -> int:
    host = Host(args.root)
    if args.undo:
        problems = undo(host, Path(args.undo))
        for problem in problems:
            print(f"not restored: {problem}")
        if not problems:
            print(f"restored everything recorded in {args.undo}")
        return 1 if problems else 0
    if args.cpu is None or args.interface is None:
        raise HostError("give 'ether-ros rt setup' --cpu and -i/--interface (or --undo FILE)")
    plan = make_plan(host, args.cpu, args.interface, args.priority)
    for note in plan.notes:
        print(f"note: {note}")
    if not plan.steps:
        print("nothing to change")
        return 0
    if not args.apply:
        for step in plan.steps:
            print(f"would {step.describe()}")
        print(f"dry run: {len(plan.steps)} change(s); add --apply to make them")
        return 0
    undo_file = Path(args.undo_file)
    problems = apply_plan(host, plan, undo_file)
    for step in plan.steps:
        print(step.describe())
    for problem in problems:
        print(f"failed: {problem}")
    print(f"undo with: ether-ros rt setup --root {args.root} --undo {undo_file}")
    return 1 if problems else 0
