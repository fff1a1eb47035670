"""``ether-ros demo [laelaps|arm]``: the Laelaps II trot (default), or the 6-axis CiA 402 arm,
on a simulated bus.

``ether-ros demo arm`` moves the arm of config/arm6.yaml with a joint trajectory sent over
ROS 2 and prints the tracking error per joint (see ``ether_ros.demo.arm``).

By default the trot is driven through the ROS 2 node (``--via ros``): the simulator and
``ether-ros run`` each run in their own process on a veth pair, and the trot of thesis Table 6.1
is published over ROS 2 only (see ``ether_ros.demo.trot``). What the ROS 2 client received is
left in ``--output`` (default ``demo-output/`` in the current directory): ``trot.mcap`` and the
thesis's Figs. 6.5-6.11 of this run as PNG, with the share of time at the PWM limit per leg and
joint printed. ``--via pysoem`` drives the same simulated bus with pysoem (SOEM) instead, a check
that needs neither our master nor ROS.

With pysoem, the demo creates a veth pair (the simulator's end in its own network
namespace), starts ``ether-ros sim`` on it as a separate process, brings the four legs to OP with
pysoem on the other end, and commands the trot of thesis Table 6.1: ``b_ellipse100`` ramps to
4 cm, then ``a_ellipse100`` to 5 cm (Transition_time 3 s each), then the legs trot. It prints how
well the legs tracked their desired angles, the cycle count and the working-counter errors, and
removes everything it created.
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path
from typing import Any

from ether_ros.cli.common import add_parser
from ether_ros.errors import EtherRosError

# The --help text: what the module docstring says, without its markup.
DESCRIPTION = """\
The Laelaps II trot (default), or the 6-axis CiA 402 arm, on a simulated bus. Needs root: it
creates a veth pair and a network namespace for the simulator and removes them afterwards.

laelaps (--via ros, the default): the simulator and 'ether-ros run' each run in their own
process; the trot of thesis Table 6.1 is published over ROS 2 only. The run's recording
(trot.mcap) and the thesis's Figs. 6.5-6.11 as PNG are left in --output, and the share of time
at the PWM limit per leg and joint is printed.

laelaps --via pysoem: the same simulated bus driven by pysoem (SOEM) instead, a check that
needs neither our master nor ROS; it prints how well the legs tracked their desired angles.

arm: moves the arm of config/arm6.yaml with a joint trajectory sent over ROS 2 and prints the
tracking error per joint."""

DEFAULT_CONFIG = Path(__file__).resolve().parents[3] / "config" / "laelaps.yaml"
ARM_CONFIG = Path(__file__).resolve().parents[3] / "config" / "arm6.yaml"


def register(subparsers: Any) -> None:
    p = add_parser(
        subparsers,
        "demo",
        help="trot the simulated Laelaps II through the ROS 2 node and print how the legs tracked",
        description=DESCRIPTION,
        examples=[
            "ether-ros demo                     # the trot through the ROS 2 node",
            "ether-ros demo -o /tmp/demo        # ... with its recording and figures there",
            "ether-ros demo --via pysoem --seconds 8",
            "ether-ros demo arm",
        ],
    )
    p.add_argument(
        "robot",
        nargs="?",
        choices=("laelaps", "arm"),
        default="laelaps",
        help="laelaps: the trot (default); arm: the 6-axis arm, a joint trajectory over ROS 2",
    )
    p.add_argument("--config", type=Path, default=None, help="bus configuration (default: "
                   "config/laelaps.yaml, config/arm6.yaml for arm)")  # fmt: skip
    p.add_argument(
        "--via",
        choices=("ros", "pysoem"),
        default="ros",
        help="drive the trot through the ROS 2 node (default) or with pysoem",
    )
    p.add_argument("--seconds", type=float, default=10.0, help="pysoem: length of the run")
    p.add_argument(
        "-o",
        "--output",
        type=Path,
        default=Path("demo-output"),
        help="laelaps via ros: directory for the run's recording and figures "
        "(default: demo-output)",
    )
    p.add_argument("--no-netns", action="store_true", help="keep the simulator's veth end in"
                   " this network namespace")  # fmt: skip
    p.set_defaults(func=run_demo)


def run_demo(args: argparse.Namespace) -> int:
    if args.robot == "arm":
        from ether_ros.demo.arm import run_arm_demo

        if args.via != "ros":
            raise EtherRosError("the arm demo runs through the ROS 2 node only (no --via pysoem)")
        return run_arm_demo(args.config or ARM_CONFIG)
    args.config = args.config or DEFAULT_CONFIG
    if args.via == "ros":
        from ether_ros.demo.trot import run_demo as run_ros_demo

        return run_ros_demo(args.config, output=args.output)
    return run_pysoem_demo(args)


def run_pysoem_demo(args: argparse.Namespace) -> int:
    from ether_ros.config import load_bus_config
    from ether_ros.netns import VethPair
    from ether_ros.sim.proof import SimProcess, SoemBus, TrackStats, table_6_1

    if os.geteuid() != 0:
        raise EtherRosError("the demo creates a veth pair and a network namespace: run as root")
    cfg = load_bus_config(args.config)
    if args.seconds < 1:
        raise EtherRosError(f"--seconds must be at least 1, got {args.seconds}")
    transition = 3 if args.seconds >= 8 else 1
    with (
        VethPair.create(netns=not args.no_netns) as veth,
        SimProcess(args.config, veth.slave, veth.netns) as sim,
    ):
        print(sim.ready_line)
        bus = SoemBus(cfg, veth.master, receive_timeout_us=5000)
        try:
            n = bus.scan()
            bus.configure()
            # Python on a shared VM can stall for tens of ms: don't let the slaves' 100 ms
            # process-data watchdog mistake that for a dead master.
            bus.set_watchdog(1000)
            legs = [i for i, s in enumerate(bus.slaves_cfg) if s.layout.has("a_ellipse100")]
            if not legs:
                raise EtherRosError(f"{args.config}: no Laelaps II legs on this bus")
            for i in legs:  # the standing pose first: a = b = 0
                bus.set_outputs(i, table_6_1(bus.slaves_cfg[i].name, 0, 0, transition))
            if not bus.request_op():
                raise EtherRosError(f"the slaves did not reach OP: {bus.states()}")
            print(f"ether-ros demo: {n} slaves in OP, expected WKC {bus.master.expected_wkc}")
            track = {i: (TrackStats(), TrackStats()) for i in legs}
            cycles_per_s = 1 / max(bus.cycle_s, 0.0004)
            b_at, a_at = 0, int(transition * cycles_per_s)
            settle = int(0.5 * cycles_per_s)

            def each(k: int) -> None:
                if k in (b_at, a_at):
                    a = 5 if k == a_at else 0
                    for i in legs:
                        bus.set_outputs(i, table_6_1(bus.slaves_cfg[i].name, a, 4, transition))
                if k >= settle and k % 10 == 0:
                    for i in legs:
                        v = bus.inputs(i)
                        track[i][0].add(v["hip_angle"] / 100, v["desired_hip_angle"] / 100)
                        track[i][1].add(v["knee_angle"] / 100, v["desired_knee_angle"] / 100)

            bus.run(args.seconds, each)
            for i in legs:
                bus.set_outputs(i, {"State_Machine": 0})
            bus.run(0.05)
            st = bus.stats
            print(f"ether-ros demo: {st.cycles} cycles, {st.wkc_errors} WKC errors"
                  f" ({st.lost} frames lost)")  # fmt: skip
            for i in legs:
                hip, knee = track[i]
                name = bus.slaves_cfg[i].name
                print(
                    f"  {name:<16} hip RMS error {hip.rms_deg:6.3f} deg (desired swings"
                    f" {hip.desired_span_deg:5.1f} deg), knee RMS error {knee.rms_deg:6.3f} deg"
                    f" (swings {knee.desired_span_deg:5.1f} deg)"
                )
        finally:
            bus.master.state = 1
            bus.master.write_state()
            bus.close()
    return 0
