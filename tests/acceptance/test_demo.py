"""`make demo` runs `ether-ros demo`: the main job must work end to end, both ways it runs."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

from ether_ros.tools.recording import read_recording

pytestmark = [pytest.mark.netns, pytest.mark.slow]


def _demo(*args: str, timeout: float) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "ether_ros.cli.main", "demo", *args],
        capture_output=True,
        text=True,
        timeout=timeout,
    )


def test_demo_trots_through_the_ros_node(tmp_path: Path) -> None:
    output = tmp_path / "demo-output"
    out = _demo("--output", str(output), timeout=420)
    assert out.returncode == 0, out.stdout + out.stderr
    legs = ("hind_right_leg", "hind_left_leg", "front_left_leg", "front_right_leg")
    # The summary names every leg of config/laelaps.yaml with its tracking error, and the
    # steady-trot report gives each leg's share of time at the PWM limit.
    for leg in legs:
        assert leg in out.stdout
        assert re.search(rf"^{leg}\s+\d+\.\d%\s+\d+\.\d%", out.stdout, re.MULTILINE), out.stdout
    # The run's recording and figures are left where the demo says.
    assert f"are in {output}/" in out.stdout, out.stdout
    figures = sorted(p.name for p in output.glob("fig6_*.png"))
    assert figures == sorted(
        f"{name}.png"
        for name in (
            "fig6_5_toe_trajectory",
            "fig6_6_knee_angle",
            "fig6_7_hip_angle",
            "fig6_8_knee_pwm",
            "fig6_9_hip_pwm",
            "fig6_10_knee_velocity",
            "fig6_11_hip_velocity",
        )
    ), out.stdout
    for name in figures:
        assert (output / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
        assert str(output / name) in out.stdout
    rec = read_recording(output / "trot.mcap")
    assert sorted(rec.inputs) == sorted(legs)
    assert rec.outputs["front_left_leg"]["a_ellipse100"].max() == 5


def test_demo_trots_through_pysoem() -> None:
    out = _demo("--via", "pysoem", "--seconds", "4", timeout=120)
    assert out.returncode == 0, out.stdout + out.stderr
    rows = re.findall(
        r"(\w+_leg)\s+hip RMS error\s+([\d.]+) deg \(desired swings\s+([\d.]+) deg\)", out.stdout
    )
    assert {leg for leg, _, _ in rows} == {
        "hind_right_leg",
        "hind_left_leg",
        "front_left_leg",
        "front_right_leg",
    }, out.stdout
    for leg, rms, swing in rows:
        # The hips really swing, and follow their desired angles far closer than the swing.
        assert float(swing) > 5.0, f"{leg} did not trot: {out.stdout}"
        assert float(rms) < float(swing) / 3, f"{leg} did not track: {out.stdout}"


def test_demo_arm_moves_the_arm_through_ros() -> None:
    out = _demo("arm", timeout=180)
    assert out.returncode == 0, out.stdout + out.stderr
    rows = re.findall(
        r"(\w+)\s+RMS error\s+([\d.]+) rad\s+max\s+([\d.]+) rad\s+\(swing ([\d.]+) rad, "
        r"ended at ([-+\d.]+) rad\)",
        out.stdout,
    )
    assert [r[0] for r in rows] == [
        "shoulder_pan", "shoulder_lift", "elbow", "wrist_1", "wrist_2", "wrist_3"
    ], out.stdout  # fmt: skip
    for joint, rms, largest, swing, _ended in rows:
        # Every joint followed its swing far closer than the swing itself.
        assert float(largest) < float(swing) / 5, f"{joint} did not track: {out.stdout}"
        assert float(rms) <= float(largest)
