"""Running ``ether-ros`` the way a user does: the CLI in its own process, from the repository
root, output captured. Shared by the acceptance tests that drive the command line."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
LAELAPS = REPO / "config" / "laelaps.yaml"


def ether_ros(*args: str, timeout: float = 180) -> subprocess.CompletedProcess[str]:
    """``ether-ros *args`` in its own process; the caller checks the return code.

    The timeout only stops a hung command (the tests never assert on timing)."""
    return subprocess.run(
        [sys.executable, "-m", "ether_ros.cli.main", *args],
        capture_output=True,
        text=True,
        timeout=timeout,
        cwd=REPO,
        check=False,
    )
