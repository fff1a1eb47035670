"""``ether-ros run CONFIG``: the ROS 2 node on a bus, configured and active unless --inactive."""

from __future__ import annotations

import argparse
import signal
import sys
from typing import Any

from ether_ros.cli.common import add_interface_argument, add_parser, resolve_interface
from ether_ros.master.link import add_link_argument

SWITCH_INTERVAL_S = 0.0005


def register(subparsers: Any) -> None:
    p = add_parser(
        subparsers,
        "run",
        help="run the ROS 2 lifecycle node on a bus",
        description="Start the ether_ros lifecycle node (name: ros.node_name of the config). "
        "By default it configures (opens and scans the bus) and activates (OP, cyclic "
        "exchange, publishing); with --inactive it waits for lifecycle transitions.\n"
        "Ctrl-C or SIGTERM deactivates it (safe outputs, SAFEOP) before it exits.",
        examples=[
            "ether-ros run config/laelaps.yaml -i eth1",
            "ether-ros run config/arm6.yaml -i eth1 --node-name arm --inactive",
        ],
    )
    p.add_argument("config", help="bus configuration (YAML)")
    add_interface_argument(p)
    add_link_argument(p)
    p.add_argument(
        "--inactive",
        action="store_true",
        help="leave the node unconfigured; the caller drives the lifecycle transitions",
    )
    p.add_argument("--node-name", help="override ros.node_name")
    p.add_argument(
        "--python-commands",
        action="store_true",
        help="serve pdo_listener from the Python executor instead of the native command thread "
        "(slower; for comparison and diagnosis)",
    )
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import rclpy
    from rclpy.executors import ExternalShutdownException
    from rclpy.signals import SignalHandlerOptions

    from ether_ros.config import load_bus_config
    from ether_ros.errors import EtherRosError
    from ether_ros.ros.node import EtherRosNode, spin

    # The interface is checked before ROS starts: a missing one or a LAN card fails here. An
    # inactive node may get its interface later, from its "interface" parameter.
    configured = load_bus_config(args.config).bus.interface
    interface: str | None = None
    if not args.inactive or args.interface or configured:
        interface = resolve_interface(args, configured, "run", args.config)

    # Signals end the spin with KeyboardInterrupt while the ROS context is still valid, so the
    # node can still deactivate cleanly (safe outputs, SAFEOP) and say so on its topics.
    rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
    # The sample publisher thread keeps the GIL busy at 2.5 kHz; a short switch interval lets a
    # write or a panic arriving in the executor run within a fraction of a millisecond instead
    # of waiting up to Python's default 5 ms for the GIL.
    sys.setswitchinterval(SWITCH_INTERVAL_S)
    signal.signal(signal.SIGTERM, _interrupt)
    node: EtherRosNode | None = None
    try:
        node = EtherRosNode(
            args.config,
            interface,
            node_name=args.node_name,
            command_node=True,
            native_commands=not args.python_commands,
            link_kind=args.link,
        )
        if not args.inactive:
            ok, message = node.run_command("start")
            if not ok:
                raise EtherRosError(message)
            print(f"ether-ros run: {node.get_fully_qualified_name()} {message}", flush=True)
        else:
            print(f"ether-ros run: {node.get_fully_qualified_name()} unconfigured", flush=True)
        spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        if node is not None:
            _shutdown(node)
        if rclpy.ok():
            rclpy.try_shutdown()
    return 0


def _interrupt(signum: int, frame: Any) -> None:
    raise KeyboardInterrupt


def _shutdown(node: Any) -> None:
    """Leave the bus safe: deactivate (safe outputs, SAFEOP) and release the interface."""
    try:
        if node.lifecycle_state() == "active":
            node.trigger_deactivate()
    except Exception as exc:  # shutting down anyway; say what went wrong
        print(f"ether-ros run: deactivating: {exc}", file=sys.stderr)
    node.destroy_node()
