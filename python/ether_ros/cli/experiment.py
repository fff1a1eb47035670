"""``ether-ros experiment trot|frequency``: the thesis's experiments (Tables 6.1 and 6.5)."""

from __future__ import annotations

import argparse
from typing import Any

from ether_ros.cli.common import add_interface_argument, add_parser, resolve_interface
from ether_ros.master.link import add_link_argument


def register(subparsers: Any) -> None:
    parser = add_parser(
        subparsers,
        "experiment",
        help="run the trot or the loop-frequency "
        "experiment of the thesis on a bus (simulated or real)",
        description="The experiments of the thesis's chapter 6 on a bus of this process "
        "(no ROS): trot (Table 6.1) and frequency (Table 6.5). See docs/laelaps.md.",
        examples=[
            "ether-ros experiment trot config/laelaps.yaml -i eth1 --record trot.mcap",
            "ether-ros experiment frequency config/laelaps.yaml -i eth1 --round-seconds 60",
        ],
    )
    sub = parser.add_subparsers(dest="experiment", metavar="EXPERIMENT", required=True)

    trot = add_parser(
        sub,
        "trot",
        help="Table 6.1: ramp b to 4 cm and a to 5 cm, trot, stop; report the PWM limits and toe",
        description="The trot of thesis §6.2.1.1 (Table 6.1): b_ellipse100 ramps to 4 cm, then "
        "a_ellipse100 to 5 cm over Transition_time, the legs trot for --hold seconds, then a and "
        "b go back to 0. Afterwards it prints, per leg and joint over the steady trot, the share "
        "of time the PWM command sat at its limit (Figs. 6.8/6.9), the peak PWM and speed "
        "(Figs. 6.10/6.11) and the toe's distance from the desired path (Fig. 6.5).",
        examples=[
            "ether-ros experiment trot config/laelaps.yaml -i eth1 --record trot.mcap",
            "ether-ros plot trot.mcap",
            "ether-ros experiment trot config/laelaps.yaml -i eth1 --hold 3 --transition 1",
        ],
    )
    trot.add_argument("config", help="bus configuration (YAML) with Laelaps II legs")
    add_interface_argument(trot)
    add_link_argument(trot)
    trot.add_argument(
        "--record",
        metavar="FILE",
        help="keep the recording of the run in this MCAP file (default: a temporary file, "
        "removed after the report)",
    )
    trot.add_argument(
        "--transition", type=int, default=3, help="Transition_time in seconds (Table 6.1: 3)"
    )
    trot.add_argument(
        "--hold",
        type=float,
        default=10.0,
        help="seconds of steady trot between the ramps (default 10)",
    )
    trot.add_argument(
        "--watchdog-ms",
        type=int,
        default=None,
        metavar="MS",
        help="override bus.watchdog_ms for this run (0: off). This process feeds the command "
        "watchdog while it waits; on a heavily loaded host its stalls can exceed the configured "
        "time and put the safe outputs on the wire mid-trot",
    )
    trot.set_defaults(func=run_trot)

    freq = add_parser(
        sub,
        "frequency",
        help="Table 6.5: lost frames per loop time, a round per step",
        description="The loop-frequency experiment of thesis §6.3 (Table 6.5): run the bus in "
        "OP for --round-seconds at each loop time from --from-us down to --to-us in --step-us "
        "steps, and print the lost frames of every round.",
        examples=[
            "ether-ros experiment frequency config/laelaps.yaml -i eth1",
            "ether-ros experiment frequency config/laelaps.yaml -i eth1 --round-seconds 10 "
            "--from-us 200 --to-us 100",
        ],
    )
    freq.add_argument("config", help="bus configuration (YAML)")
    add_interface_argument(freq)
    add_link_argument(freq)
    freq.add_argument("--from-us", type=int, default=400, help="first loop time (default 400)")
    freq.add_argument("--step-us", type=int, default=50, help="decrement per round (default 50)")
    freq.add_argument("--to-us", type=int, default=100, help="last loop time (default 100)")
    freq.add_argument(
        "--round-seconds",
        type=float,
        default=600.0,
        help="length of each round (Table 6.3: 10 minutes)",
    )
    freq.add_argument(
        "--record",
        metavar="FILE",
        help="record each round to FILE with _<loop>us before the suffix",
    )
    freq.set_defaults(func=run_frequency)


def run_trot(args: argparse.Namespace) -> int:
    import tempfile
    from pathlib import Path

    from ether_ros.tools.experiments import ExperimentError, TrotPlan, trot
    from ether_ros.tools.session import load_config, running_bus
    from ether_ros.tools.trot_metrics import format_trot_report

    config = load_config(args.config, args.interface, args.link)
    if args.watchdog_ms is not None:
        if not 0 <= args.watchdog_ms <= 60_000:
            raise ExperimentError(f"--watchdog-ms must be 0..60000, got {args.watchdog_ms}")
        config.bus.watchdog_ms = args.watchdog_ms
    interface = resolve_interface(args, config.bus.interface, "experiment trot", args.config)
    with tempfile.TemporaryDirectory(prefix="ether-ros-trot-") as scratch:
        # The report is read from the recording: without --record, a temporary one.
        record = Path(args.record) if args.record else Path(scratch) / "trot.mcap"
        with running_bus(config, interface) as bus:
            result = trot(bus, TrotPlan(transition_s=args.transition, hold_s=args.hold), record)
    legs = ", ".join(f"{name}={leg}" for name, leg in result.legs.items())
    print(
        f"trot done: legs {legs}; {result.lost_frames} lost frames, "
        f"{result.watchdog_trips} watchdog trips"
    )
    if result.watchdog_trips:
        print(
            "note: the command watchdog put the safe outputs on the wire during the run "
            "(this process stalled longer than bus.watchdog_ms); the legs went to "
            "Configurational meanwhile, which shows in the figures and the report "
            "(--watchdog-ms sets another time for the run)"
        )
    print(format_trot_report(result.report))
    if args.record:
        print(
            f"{result.recording}: {result.cycles_recorded} cycles "
            f"(plot with: ether-ros plot {result.recording})"
        )
    return 0


def run_frequency(args: argparse.Namespace) -> int:
    from ether_ros.master.bus import Bus
    from ether_ros.tools.experiments import frequency, frequency_table, loop_times
    from ether_ros.tools.session import load_config

    steps = loop_times(args.from_us, args.step_us, args.to_us)
    # A bad configuration or interface fails before round one.
    configured = load_config(args.config, args.interface).bus.interface
    interface = resolve_interface(args, configured, "experiment frequency", args.config)

    def open_bus(cycle_us: int) -> Any:
        config = load_config(args.config, interface, args.link)
        config.bus.cycle_us = cycle_us
        return Bus.open(config, interface=interface)

    rounds = frequency(open_bus, steps, args.round_seconds, record=args.record)
    print(frequency_table(rounds))
    return 0
