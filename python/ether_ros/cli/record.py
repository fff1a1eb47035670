"""``ether-ros record CONFIG --interface IFACE --seconds S -o FILE``: record a standalone bus."""

from __future__ import annotations

import argparse
import time
from typing import Any

from ether_ros.cli.common import add_interface_argument, add_parser, resolve_interface
from ether_ros.master.link import add_link_argument


def register(subparsers: Any) -> None:
    parser = add_parser(
        subparsers,
        "record",
        help="bring a bus to OP and record its cycles to an MCAP file",
        description="Open the bus of CONFIG in this process (no ROS), bring it to OP and record "
        "its decoded values (and, with --raw-decimation, the raw process images) and the loop "
        "timing to an MCAP file for --seconds; then stop the bus (safe outputs, SAFEOP).",
        examples=[
            "ether-ros record config/laelaps.yaml -i eth1 --seconds 5 -o run.mcap",
            "ether-ros plot run.mcap",
        ],
    )
    parser.add_argument("config", help="bus configuration (YAML)")
    add_interface_argument(parser)
    add_link_argument(parser)
    parser.add_argument(
        "--seconds",
        type=float,
        default=10.0,
        help="how long to record (default 10; Ctrl-C stops earlier)",
    )
    parser.add_argument("-o", "--output", required=True, help="the MCAP file to write")
    parser.add_argument(
        "--decimation",
        type=int,
        default=None,
        help="decoded values every N cycles (default: ros.decoded_decimation)",
    )
    parser.add_argument(
        "--raw-decimation",
        type=int,
        default=0,
        help="raw process images every N cycles (default 0: none)",
    )
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from ether_ros.errors import EtherRosError
    from ether_ros.tools.bus_source import BusSampleSource, bus_info
    from ether_ros.tools.recording import Recorder, RecordingWriter
    from ether_ros.tools.session import load_config, running_bus

    if args.seconds <= 0:
        raise EtherRosError(f"--seconds must be positive, got {args.seconds}")
    config = load_config(args.config, args.interface, args.link)
    interface = resolve_interface(args, config.bus.interface, "record", args.config)
    decimation = args.decimation or config.ros.decoded_decimation
    with running_bus(config, interface) as bus:
        writer = RecordingWriter(
            args.output, bus_info(bus), bus.config.joint_specs(), metadata={"command": "record"}
        )
        recorder = Recorder(BusSampleSource(bus, decimation, args.raw_decimation), writer)
        recorder.start()
        try:
            time.sleep(args.seconds)
        except KeyboardInterrupt:
            pass
        finally:
            recorder.stop()
    print(f"{args.output}: {writer.cycles} cycles")
    return 0
