"""``ether-ros sim``: run the simulated bus of a config on a network interface, and
``ether-ros sim-fault``: inject faults into (or query) a running simulator."""

from __future__ import annotations

import argparse
import json
import os
import signal
import sys
from pathlib import Path
from typing import Any

from ether_ros.cli.common import add_interface_argument, add_parser, resolve_interface
from ether_ros.errors import ConfigError, LinkError
from ether_ros.master.link import LINKS

_FAULT_HELP = {
    "drop": "drop frames: each frame starts a burst of BURST lost frames with probability RATE",
    "corrupt": "flip bytes in answered frames with probability RATE",
    "delay": "answer every frame US microseconds late",
    "reset": "power-cycle a slave (it falls back to INIT)",
    "refuse-op": "make a slave refuse SAFEOP->OP (--off to stop)",
    "link": "pull (down) or plug (up) the cable; --at SLAVE breaks the link before that slave,"
    " --at SLAVE --port P the one on its port P; 'link up' without --at plugs every cable back",
    "drift-step": "change a slave's clock drift by PPM",
    "stall-mailbox": "a slave stops answering mailbox requests (--off to stop)",
    "drive-fault": "raise a fault in one axis of a CiA 402 drive (cleared by a fault reset)",
    "clear": "remove all faults (frames and slaves behave normally again)",
    "stats": "print the simulator's frame counters (JSON)",
    "slave-info": "print a slave's ESC state (JSON)",
    "probe": "print a slave's device physics (JSON)",
}

# One example per fault, shown in its --help (arguments after "ether-ros sim-fault -i veth1").
_FAULT_EXAMPLE = {
    "drop": "drop --rate 0.01 --burst 3",
    "corrupt": "corrupt --rate 0.001",
    "delay": "delay --us 200",
    "reset": "reset 2",
    "refuse-op": "refuse-op front_left_leg",
    "link": "link down --at 2",
    "drift-step": "drift-step 1 50",
    "stall-mailbox": "stall-mailbox 0",
    "drive-fault": "drive-fault 0 encoder --axis 2",
    "clear": "clear",
    "stats": "stats",
    "slave-info": "slave-info 0",
    "probe": "probe front_left_leg",
}


def _fault_parser(kinds: Any, name: str) -> Any:
    return add_parser(
        kinds,
        name,
        help=_FAULT_HELP[name],
        description=_FAULT_HELP[name][0].upper() + _FAULT_HELP[name][1:] + ".",
        examples=[f"ether-ros sim-fault -i veth1 {_FAULT_EXAMPLE[name]}"],
    )


def register(subparsers: Any) -> None:
    p = add_parser(
        subparsers,
        "sim",
        help="run a simulated EtherCAT bus on a network interface",
        description="Run the slaves of CONFIG (or COUNT slaves of one device of an ESI file) as"
        " virtual EtherCAT slaves answering frames on INTERFACE until SIGINT/SIGTERM. Prints"
        " one line when ready. Give it one end of a veth pair and the master the other end"
        " (docs/simulator.md).",
        examples=[
            "ip link add veth0 type veth peer name veth1 && ip link set veth0 up && "
            "ip link set veth1 up",
            "ether-ros sim config/laelaps.yaml -i veth1",
            "ether-ros sim --esi devices/laelaps_leg.xml --count 4 -i veth1 --no-control",
        ],
    )
    p.add_argument("config", type=Path, nargs="?", help="bus configuration (YAML)")
    p.add_argument("--esi", type=Path, help="run slaves of this ESI file instead of a config")
    p.add_argument("--device", help="with --esi: the device <Type> (needed when the file has"
                   " several)")  # fmt: skip
    p.add_argument("--count", type=int, default=1, help="with --esi: how many slaves (default 1)")
    add_interface_argument(p, "network interface the slaves answer on (default: bus.interface)")
    p.add_argument(
        "--link",
        choices=LINKS,
        default="packet",
        help="how the simulator receives and answers: AF_PACKET (default), AF_XDP, or AF_XDP"
        " when available",
    )
    p.add_argument(
        "--threads",
        type=_threads,
        default=None,
        help="worker threads running the device firmware, apart from the frame thread"
        " (default: one per CPU the simulator may use; 0: the frame thread runs it)",
    )
    p.add_argument(
        "--timing",
        choices=("fast", "wire"),
        default="fast",
        help="when an answer leaves: as soon as it is processed (fast, default) or when the"
        " modelled 100 Mbit/s wire would have brought it back (wire)",
    )
    p.add_argument("--control", type=Path, help="control socket path (default:"
                   " /run/ether_ros/sim-INTERFACE.sock)")  # fmt: skip
    p.add_argument("--no-control", action="store_true", help="no control socket")
    p.add_argument("--seed", type=int, default=1, help="seed of the fault-injection random"
                   " generator (default 1)")  # fmt: skip
    p.set_defaults(func=run_sim)

    f = add_parser(
        subparsers,
        "sim-fault",
        help="inject a fault into a running simulator (or query it)",
        description="Talk to the control socket of a running 'ether-ros sim': inject a fault,"
        " clear them, or print its counters and a slave's state (JSON).",
        examples=[
            "ether-ros sim-fault -i veth1 drop --rate 0.01 --burst 3",
            "ether-ros sim-fault -i veth1 link down --at 2",
            "ether-ros sim-fault -i veth1 clear",
            "ether-ros sim-fault -i veth1 stats",
        ],
    )
    add_interface_argument(f, "interface the simulator runs on (names its control socket)",
                           opens=False)  # fmt: skip
    f.add_argument("--control", type=Path, help="control socket path")
    kinds = f.add_subparsers(dest="fault", metavar="FAULT", required=True)
    k = _fault_parser(kinds, "drop")
    k.add_argument("--rate", type=float, required=True)
    k.add_argument("--burst", type=int, help="frames dropped per burst (default: Drop's)")
    k = _fault_parser(kinds, "corrupt")
    k.add_argument("--rate", type=float, required=True)
    k.add_argument("--bytes", type=int, help="bytes flipped per frame (default: Corrupt's)")
    k = _fault_parser(kinds, "delay")
    k.add_argument("--us", type=int, required=True)
    for name in ("reset", "refuse-op", "stall-mailbox", "slave-info", "probe"):
        k = _fault_parser(kinds, name)
        k.add_argument("slave", help="slave name or position")
        if name in ("refuse-op", "stall-mailbox"):
            k.add_argument("--off", action="store_true", help="end this fault")
    k = _fault_parser(kinds, "link")
    k.add_argument("state", choices=["up", "down"])
    k.add_argument("--at", help="slave name or position: break the link in front of it")
    k.add_argument(
        "--port",
        type=int,
        choices=[0, 1, 2, 3],
        help="with --at: break the link on this port of that slave instead (a branch)",
    )
    k = _fault_parser(kinds, "drift-step")
    k.add_argument("slave", help="slave name or position")
    k.add_argument("ppm", type=float)
    k = _fault_parser(kinds, "drive-fault")
    k.add_argument("slave", help="slave name or position")
    k.add_argument("error", type=_drive_fault, help="over_current, encoder, under_voltage or"
                   " following_error")  # fmt: skip
    k.add_argument(
        "--axis", type=_axis, help="axis 1..8 of the drive (default: DriveFault's, the first)"
    )
    _fault_parser(kinds, "clear")
    _fault_parser(kinds, "stats")
    f.set_defaults(func=run_fault)


MAX_THREADS = 64  # the simulator's own limit (SimNetwork.run_on_interface)


def _threads(text: str) -> int:
    """A firmware thread count for ``--threads`` (0..MAX_THREADS)."""
    try:
        n = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected a number 0..{MAX_THREADS}, got {text!r}"
        ) from None
    if not 0 <= n <= MAX_THREADS:
        raise argparse.ArgumentTypeError(f"expected a number 0..{MAX_THREADS}, got {n}")
    return n


def _serve(net: Any, iface: str, link: str, threads: int | None, timing: str) -> None:
    """Start the simulator's frame thread and firmware workers on ``iface`` through ``link``;
    ``auto`` falls back to AF_PACKET with one line on stderr."""
    if link == "auto":
        try:
            net.run_on_interface(iface, "xdp", threads=threads, timing=timing)
            return
        except OSError as exc:
            print(f"ether-ros sim: no AF_XDP ({exc}); using AF_PACKET", file=sys.stderr)
            link = "packet"
    try:
        net.run_on_interface(iface, link, threads=threads, timing=timing)
    except OSError as exc:
        raise LinkError(str(exc)) from None


def _threads_line(net: Any) -> str:
    """How the simulator uses the machine, for its ready line."""
    fw = net.stats()["firmware"]
    where = (
        f"firmware on {fw['threads']} worker thread{'s' if fw['threads'] != 1 else ''}"
        if fw["threads"]
        else "firmware in the frame thread"
    )
    return (
        f"{where} + 1 frame thread, {fw['cpus']} CPU{'s' if fw['cpus'] != 1 else ''}"
        f" available; timing {fw['timing']}"
    )


def _drive_fault(text: str) -> str:
    """A drive fault name for ``drive-fault`` (the control socket's table; imported only when
    parsing one, so the command line starts without the simulator front)."""
    from ether_ros.sim.control import DRIVE_FAULTS

    if text not in DRIVE_FAULTS:
        raise argparse.ArgumentTypeError(
            f"unknown drive fault {text!r} (known: {', '.join(DRIVE_FAULTS)})"
        )
    return text


def _axis(text: str) -> int:
    """An axis number for ``drive-fault --axis`` (1-based)."""
    from ether_ros.sim.control import MAX_AXES

    try:
        axis = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"axis must be a number 1..{MAX_AXES}, got {text!r}"
        ) from None
    if not 1 <= axis <= MAX_AXES:
        raise argparse.ArgumentTypeError(f"axis must be 1..{MAX_AXES}, got {axis}")
    return axis


def run_sim(args: argparse.Namespace) -> int:
    from ether_ros.config import load_bus_config
    from ether_ros.sim.control import InterfaceLock
    from ether_ros.sim.network import build_network

    if (args.config is None) == (args.esi is None):
        raise ConfigError("give a bus configuration or --esi FILE (one of them)")
    if args.esi is not None:
        from ether_ros.config.from_esi import bus_config_for_esi

        if not args.interface:
            raise ConfigError("'ether-ros sim --esi' needs -i/--interface")
        cfg = bus_config_for_esi(args.esi, args.device, args.count, interface=args.interface)
    else:
        if args.device is not None or args.count != 1:
            raise ConfigError("--device and --count go with --esi")
        cfg = load_bus_config(args.config, interface=args.interface)
    iface = resolve_interface(args, cfg.bus.interface, "sim", args.config)
    if not 0 <= args.seed < 2**64:
        raise ConfigError(f"--seed must be 0..2^64-1, got {args.seed}")
    lock = InterfaceLock(iface)
    try:
        net = build_network(cfg, seed=args.seed)
        rc = _run(net, cfg, iface, args)
    finally:
        lock.release()
    # The frame loop has stopped and the control socket is gone: end now. Tearing down an
    # interpreter with the config stack loaded takes a second on a loaded machine, and a
    # restart must not wait for it (nothing is left to clean up: the kernel holds nothing).
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(rc)


def _run(net: Any, cfg: Any, iface: str, args: argparse.Namespace) -> int:
    """Serve until SIGINT/SIGTERM: the signals are taken synchronously (``sigtimedwait``), so
    the frame loop stops as soon as one arrives; the control socket goes after it."""
    from ether_ros.sim.control import ControlServer, socket_path
    from ether_ros.sim.network import handle_request, slave_names

    signals = {signal.SIGINT, signal.SIGTERM}
    # Blocked before any thread starts, so that every thread inherits the mask and the
    # signal waits for the main thread's sigtimedwait below.
    old_mask = signal.pthread_sigmask(signal.SIG_BLOCK, signals)
    server = None
    try:
        if not args.no_control:
            path = args.control or socket_path(iface)
            server = ControlServer(
                path, slave_names(cfg), lambda op, kind, a: handle_request(net, op, kind, a)
            )
        _serve(net, iface, args.link, args.threads, args.timing)
        if server is not None:
            server.start()
        print(f"ether-ros sim: {len(cfg.slaves)} slaves on {iface} ready", flush=True)
        print(f"ether-ros sim: {_threads_line(net)}", flush=True)
        while signal.sigtimedwait(signals, 0.2) is None:
            if not _running(net):
                print("ether-ros sim: the frame loop stopped", file=sys.stderr)
                return 1
    finally:
        net.stop()
        if server is not None:
            server.close()
        signal.pthread_sigmask(signal.SIG_SETMASK, old_mask)
    return 0


def _running(net: Any) -> bool:
    return bool(getattr(net, "running", True))


def fault_request(args: argparse.Namespace) -> dict[str, Any]:
    """The control request for parsed ``sim-fault`` arguments."""
    name = args.fault
    if name == "stats":
        return {"op": "stats"}
    if name in ("slave-info", "probe"):
        return {"op": name.replace("-", "_"), "slave": args.slave}
    kind = name.replace("-", "_")
    req: dict[str, Any] = {"op": "fault", "kind": kind}
    # An option left out is left out of the request: the fault type holds its default.
    if name == "drop":
        req.update(rate=args.rate, burst=args.burst)
    elif name == "corrupt":
        req.update(rate=args.rate, bytes=args.bytes)
    elif name == "delay":
        req.update(us=args.us)
    elif name in ("reset",):
        req.update(slave=args.slave)
    elif name in ("refuse-op", "stall-mailbox"):
        req.update(slave=args.slave, on=not args.off)
    elif name == "link":
        req.update(up=args.state == "up")
        if args.at is not None:
            req.update(at=args.at)
        if args.port is not None:
            req.update(port=args.port)
    elif name == "drift-step":
        req.update(slave=args.slave, ppm=args.ppm)
    elif name == "drive-fault":
        req.update(slave=args.slave, error=args.error, axis=args.axis)
    return {k: v for k, v in req.items() if v is not None}


def run_fault(args: argparse.Namespace) -> int:
    from ether_ros.sim.control import ControlError, request, socket_path

    if args.control is None and not args.interface:
        raise ControlError("give --interface (or --control PATH) of the running simulator")
    path = args.control or socket_path(args.interface)
    result = request(path, fault_request(args))
    if result is not None:
        print(json.dumps(result, indent=2, sort_keys=True))
    return 0
