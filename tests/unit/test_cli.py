"""The command-line entry point itself."""

from __future__ import annotations

import subprocess
import sys


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
