"""The operator console against a running node (simulator and node in their own processes on a
veth pair): commands, refused commands, a sequence file, and the panic key."""

from __future__ import annotations

import subprocess
import sys
import threading
from collections.abc import Iterator
from pathlib import Path

import pytest
from prompt_toolkit.input import create_pipe_input
from prompt_toolkit.output import DummyOutput

from ether_ros.console.app import Console, repl, run_lines
from ether_ros.ros.rig import RosRig

pytestmark = [pytest.mark.netns, pytest.mark.ros, pytest.mark.slow]

REPO = Path(__file__).resolve().parents[2]
STANDING = (
    "x_cntr_traj1000=0 y_cntr_traj1000=599 a_ellipse100=0 b_ellipse100=0 traj_freq100=100 "
    "phase_deg=0 FlatnessParam100=0"
)


@pytest.fixture(scope="module")
def rig(veth_allowed: bool) -> Iterator[RosRig]:
    if not veth_allowed:
        pytest.fail("the ROS acceptance tests need root (veth pairs)")
    with RosRig(REPO / "config" / "laelaps.yaml") as rig:
        assert rig.client.wait_for_node() == "active"
        rig.client.layout(timeout=10)
        yield rig


def console(rig: RosRig, *args: str, stdin: str | None = None) -> subprocess.CompletedProcess[str]:
    # The node's control lease is on (config/laelaps.yaml): the test's own client hands it over,
    # the console process acquires it at its first command and gives it back when it ends.
    rig.client.release_lease()
    return subprocess.run(
        [sys.executable, "-m", "ether_ros.cli.main", "console", *args],
        input=stdin if stdin is not None else "",
        env=rig.env,
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )


def wire(rig: RosRig, slave: str, variable: str, value: float) -> None:
    rig.client.wait_for(
        lambda latest: latest.outputs.get(slave, {}).get(variable) == value, timeout=5
    )


def test_commands_reach_the_slaves(rig: RosRig) -> None:
    r = console(  # the command line tool, its own process: ROS 2 is the only way in
        rig,
        "-c", "set all State_Machine=0 Transition_time=0",
        "-c", f"set front_right_leg {STANDING}",
        "-c", "set 3 b_ellipse100=2",
        "-c", "states",
    )  # fmt: skip
    assert r.returncode == 0, r.stdout + r.stderr
    assert "wrote front_right_leg.b_ellipse100=2" in r.stdout
    assert "node /ether_comm: active" in r.stdout
    wire(rig, "front_right_leg", "b_ellipse100", 2.0)
    rig.client.wait_for(
        lambda _l: rig.sim("probe", slave=3)["traj_b_m"] == pytest.approx(0.02), timeout=5
    )


@pytest.mark.parametrize(
    ("line", "reason"),
    [
        ("set front_right_leg a_ellipse100=30", "outside the leg workspace"),
        ("set front_right_leg Kp100_knee=99999", "outside -32768..32767"),
        ("set all hip_angle=1", "no slave has the output variable"),
        ("launch missiles", "unknown command 'launch'"),
    ],
)
def test_invalid_commands_get_a_message_and_write_nothing(
    rig: RosRig, line: str, reason: str
) -> None:
    rig.client.write("front_right_leg", "Kp100_knee", 4321)
    wire(rig, "front_right_leg", "Kp100_knee", 4321.0)
    before = dict(
        rig.client.wait_for(
            lambda latest: (
                latest.commanded.get("front_right_leg", {}).get("Kp100_knee") == 4321.0
                and latest.commanded["front_right_leg"]
            ),
            timeout=5,
        )
    )
    printed: list[str] = []
    status = run_lines(Console(rig.client, out=printed.append), [line, "set 3 Kp100_knee=1"])
    assert status == 1
    assert reason in printed[-1]
    # The run stopped at the bad line: the next (valid) line was not sent either.
    rig.client.wait_for(
        lambda latest: latest.commanded.get("front_right_leg", {}).get("Kp100_knee") == 4321.0,
        timeout=5,
    )
    after = rig.client.latest.commanded["front_right_leg"]
    assert {k: v for k, v in after.items() if k in before} == before


def test_sequence_file_runs_step_by_step(rig: RosRig, tmp_path: Path) -> None:
    seq = tmp_path / "lift.yaml"
    seq.write_text(
        "steps:\n"
        "  - set all State_Machine=0 Transition_time=0\n"
        f"  - set hind_left_leg {STANDING}\n"
        "  - wait: 0.2\n"
        "  - set: {target: hind_left_leg, values: {b_ellipse100: 3}}\n"
    )
    r = console(rig, "--run", str(seq))
    assert r.returncode == 0, r.stdout + r.stderr
    assert "[4/4] set hind_left_leg b_ellipse100=3" in r.stdout
    rig.client.wait_for(
        lambda _l: rig.sim("probe", slave=1)["traj_b_m"] == pytest.approx(0.03), timeout=5
    )
    bad = tmp_path / "bad.yaml"
    bad.write_text(
        "steps:\n  - set hind_left_leg b_ellipse100=3\n  - set hind_left_leg a_ellipse100=40\n"
    )
    printed: list[str] = []
    assert run_lines(Console(rig.client, out=printed.append), [f"run {bad}"]) == 1
    assert "bad.yaml: step 2: " in printed[-1] and "invalid ellipse" in printed[-1]


def test_panic_key_and_panic_command(rig: RosRig) -> None:
    c = rig.client
    c.command("clear_panic")
    assert c.write("hind_right_leg", "Kp100_hip", 2222)[0]
    wire(rig, "hind_right_leg", "Kp100_hip", 2222.0)
    printed: list[str] = []
    with create_pipe_input() as keys:
        done = threading.Event()
        result: list[int] = []

        def run() -> None:
            result.append(repl(Console(c, out=printed.append), None, keys, DummyOutput()))
            done.set()

        thread = threading.Thread(target=run, daemon=True)
        thread.start()
        keys.send_text("set hind_rig")  # a half-typed line does not delay the panic key
        keys.send_text("\x10")  # Ctrl-P
        wire(rig, "hind_right_leg", "Kp100_hip", 0.0)
        c.wait_for(lambda _l: c.master_status().get("panic") == "true", timeout=5)
        keys.send_text("\x15clear\r")  # Ctrl-U clears the line, then the clear command
        wire(rig, "hind_right_leg", "Kp100_hip", 2222.0)
        keys.send_text("\x1bOP")  # F1
        wire(rig, "hind_right_leg", "Kp100_hip", 0.0)
        keys.send_text("clear\rquit\r")
        assert done.wait(20)
    assert result == [0]
    assert sum(line.startswith("PANIC: ") for line in printed) == 2
    r = console(rig, stdin="panic\nclear\n")  # commands from stdin
    assert r.returncode == 0 and "PANIC: panic: safe outputs" in r.stdout
