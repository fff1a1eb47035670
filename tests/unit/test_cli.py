"""The command-line entry point itself."""

from __future__ import annotations

import argparse
import subprocess
import sys
from pathlib import Path

import yaml


def test_help_lists_commands_and_version_prints() -> None:
    out = subprocess.run(
        [sys.executable, "-m", "ether_ros.cli.main", "--version"], capture_output=True, text=True
    )
    assert out.returncode == 0
    assert out.stdout.startswith("ether-ros ")


def test_no_command_is_a_usage_error() -> None:
    out = subprocess.run(
        [sys.executable, "-m", "ether_ros.cli.main"], capture_output=True, text=True
    )
    assert out.returncode == 2


def _commands(
    parser: argparse.ArgumentParser, path: str = ""
) -> dict[str, argparse.ArgumentParser]:
    """Every leaf command of the parser tree, by its words (``"bench cycle"``)."""
    subs = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    if not subs:
        return {path.strip(): parser}
    found: dict[str, argparse.ArgumentParser] = {}
    for name, child in subs[0].choices.items():
        found.update(_commands(child, f"{path} {name}"))
    return found


# Commands that take --interface without opening it for EtherCAT frames.
NOT_OPENING = {
    "rt check": "reads the NIC's settings (IRQs, coalescing) only",
    "rt setup": "changes the NIC's settings only",
    "sim-fault": "talks to the simulator's control socket, named after the interface",
}


def test_every_command_that_opens_an_interface_takes_link() -> None:
    from ether_ros.cli.main import build_parser

    commands = _commands(build_parser())
    opening = {
        name: p
        for name, p in commands.items()
        if "--interface" in p._option_string_actions and name not in NOT_OPENING
    }
    assert {"run", "slaves", "bench cycle", "sim", "record", "top"} <= set(opening)
    for name, p in opening.items():
        link = p._option_string_actions.get("--link")
        assert link is not None, f"ether-ros {name} has --interface but no --link"
        assert tuple(link.choices or ()) == ("packet", "xdp", "auto"), name


def test_hostile_configs_end_ether_ros_run_with_one_line_not_a_traceback(tmp_path: Path) -> None:
    """Issue 19: a ROS period beyond int64 or an invalid namespace got through the config and
    crashed ``ether-ros run`` with a traceback; a bad --node-name likewise."""
    repo = Path(__file__).resolve().parents[2]
    base = yaml.safe_load((repo / "config" / "laelaps.yaml").read_text())
    base["esi"] = [str(repo / "devices")]
    cases = [
        ({"namespace": "/1robot"}, [], "ros.namespace"),
        ({"namespace": "/ro\0bot"}, [], "ros.namespace"),
        ({"snapshot_period_ms": 2**62}, [], "ros.snapshot_period_ms"),
        ({}, ["--node-name", "bad name"], "node name"),
    ]
    for n, (ros, extra, field) in enumerate(cases):
        config = tmp_path / f"bus{n}.yaml"
        config.write_text(yaml.safe_dump({**base, "ros": {**base["ros"], **ros}}))
        out = subprocess.run(
            # An interface that does not exist: the config and the node name fail before it.
            [sys.executable, "-m", "ether_ros.cli.main", "run", str(config), "-i", "nosuchif0",
             *extra],
            capture_output=True, text=True, timeout=120,
        )  # fmt: skip
        assert out.returncode == 2, (field, out.stdout, out.stderr)
        assert "Traceback" not in out.stderr, out.stderr
        lines = out.stderr.strip().splitlines()
        assert len(lines) == 1 and field in lines[0], out.stderr
