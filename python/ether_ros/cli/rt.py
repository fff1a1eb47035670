"""``ether-ros rt check`` and ``ether-ros rt setup``: the real-time host."""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

from ether_ros.tools.host import Host, HostError
from ether_ros.tools.rt_check import FAIL, CheckOptions, format_table, run_checks
from ether_ros.tools.rt_setup import apply_plan, make_plan, undo

DEFAULT_UNDO_FILE = "ether-ros-rt-undo.json"


def register(subparsers: Any) -> None:
    rt = subparsers.add_parser("rt", help="check or prepare this host for real-time operation")
    sub = rt.add_subparsers(dest="rt_command", metavar="ACTION", required=True)

    check = sub.add_parser("check", help="pass/warn/fail table of the host's real-time tuning")
    check.add_argument("--root", default="/", help="host root to inspect (default /)")
    check.add_argument("--interface", help="the EtherCAT network interface")
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

    setup = sub.add_parser("setup", help="apply the runtime tuning (dry run unless --apply)")
    setup.add_argument("--root", default="/", help="host root to change (default /)")
    setup.add_argument("--cpu", type=int, help="the CPU to dedicate to the RT thread")
    setup.add_argument("--interface", help="the EtherCAT network interface")
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
        raise HostError("rt setup needs --cpu and --interface (or --undo FILE)")
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
