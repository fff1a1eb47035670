"""``ether-ros plot RECORDING``: the thesis's trot figures and the loop timing as PNG and SVG."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from ether_ros.cli.common import add_parser


def register(subparsers: Any) -> None:
    parser = add_parser(
        subparsers,
        "plot",
        help="figures of a recording (toe path, angles, PWM, velocities, loop timing)",
        description="Write the thesis's trot figures 6.5-6.11 (toe path, knee and hip angles, "
        "PWM commands, velocities, each against its limits) and the loop timing histograms of "
        "a recording as images, and print the steady-trot report (share of time at the PWM "
        "limit per leg and joint, toe path error).",
        examples=["ether-ros plot trot.mcap", "ether-ros plot trot.mcap -o figures --format png"],
    )
    parser.add_argument(
        "recording", help="an MCAP file written by `ether-ros record` or an experiment"
    )
    parser.add_argument(
        "-o",
        "--output",
        default=None,
        help="output directory (default: <recording>_plots next to the file)",
    )
    parser.add_argument(
        "--format", default="png,svg", help="comma-separated image formats (default png,svg)"
    )
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    # Imported here: matplotlib takes a while to load and other commands do not need it.
    import matplotlib

    matplotlib.use("Agg")
    from ether_ros.tools.plots import build_figures, save_figures
    from ether_ros.tools.recording import RecordingError, read_recording
    from ether_ros.tools.trot_metrics import format_trot_report, trot_report

    formats = [f.strip().lower() for f in args.format.split(",") if f.strip()]
    unknown = [f for f in formats if f not in ("png", "svg", "pdf")]
    if unknown or not formats:
        raise RecordingError(
            f"unknown image format {', '.join(unknown) or '(none)'}: use png, svg or pdf"
        )
    recording = read_recording(args.recording)
    out = (
        Path(args.output)
        if args.output
        else Path(args.recording).with_name(Path(args.recording).stem + "_plots")
    )
    for path in save_figures(build_figures(recording), out, formats):
        print(path)
    report = trot_report(recording)
    if report:
        print(format_trot_report(report))
    return 0
