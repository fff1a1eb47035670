"""The operator console against a running node (simulator and node in their own processes on a
veth pair): commands, refused commands, a sequence file; on a terminal (a pty, the console in its
own process): the panic keys during a running sequence, Ctrl-C, a 100k paste, step mode; and
screens that tell the truth about a node that just started or is gone."""

from __future__ import annotations

import math
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from ether_ros.console.app import Console, run_lines
from ether_ros.ros.rig import RosRig
from ether_ros.testing.configs import config_with_watchdog
from ether_ros.testing.pty import CTRL_P, F1, Pty
from ether_ros.testing.wait import wait_for

pytestmark = [pytest.mark.netns, pytest.mark.ros, pytest.mark.slow]

REPO = Path(__file__).resolve().parents[2]
STANDING = (
    "x_cntr_traj1000=0 y_cntr_traj1000=599 a_ellipse100=0 b_ellipse100=0 traj_freq100=100 "
    "phase_deg=0 FlatnessParam100=0"
)


@pytest.fixture(scope="module")
def rig(veth_allowed: bool, tmp_path_factory: pytest.TempPathFactory) -> Iterator[RosRig]:
    if not veth_allowed:
        pytest.fail("the ROS acceptance tests need root (veth pairs)")
    # A 1 s engine watchdog instead of 100 ms: a trip voids the commands before it, and the
    # node's feeder can stall 100 ms on a loaded VM (testing/configs.py).
    config = config_with_watchdog("laelaps.yaml", tmp_path_factory.mktemp("console"), 1000)
    with RosRig(config) as rig:
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
    with Console(rig.client, out=printed.append) as con:
        status = run_lines(con, [line, "set 3 Kp100_knee=1"])
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
    with Console(rig.client, out=printed.append) as con:
        assert run_lines(con, [f"run {bad}"]) == 1
    assert "bad.yaml: step 2: " in printed[-1] and "invalid ellipse" in printed[-1]


def pty_console(rig: RosRig, *args: str) -> Pty:
    """The console as an operator runs it: its own process, on a terminal. The test's client
    hands the control lease over first (config/laelaps.yaml has it on): the console acquires
    it at its first command that needs it and gives it back when it ends."""
    rig.client.release_lease()
    env = dict(rig.env, PROMPT_TOOLKIT_NO_CPR="1")  # the test's terminal answers no queries
    term = Pty([sys.executable, "-m", "ether_ros.cli.main", "console", *args], env=env)
    term.expect("ether_ros>", timeout=60)
    return term


def leg_value(rig: RosRig, variable: str = "Kp100_hip", slave: str = "hind_right_leg") -> float:
    return rig.client.latest.outputs.get(slave, {}).get(variable, math.nan)


def panicked(rig: RosRig) -> bool:
    return rig.client.master_status().get("panic") == "true"


def commanded(rig: RosRig, value: float) -> None:
    """Panic cleared, the outputs following the commands, hind_right_leg Kp100_hip = value."""
    c = rig.client
    assert c.command("clear_panic")[0]
    assert c.write("hind_right_leg", "Kp100_hip", value)[0]
    wire(rig, "hind_right_leg", "Kp100_hip", value)
    wait_for("the panic to clear in the diagnostics", lambda: not panicked(rig), 20)


@pytest.mark.parametrize("key", [CTRL_P, F1], ids=["ctrl-p", "f1"])
def test_panic_key_during_a_long_wait_interrupts_the_sequence(
    rig: RosRig, tmp_path: Path, key: bytes
) -> None:
    """The issue's case: a sequence waits; the panic key puts the safe outputs on the wire
    while the wait still runs (the step after it never ran), and the sequence stops."""
    commanded(rig, 1111)
    seq = tmp_path / "hold.yaml"
    seq.write_text(
        "steps:\n"
        "  - set hind_right_leg Kp100_hip=2222\n"
        "  - wait: 600\n"
        "  - set hind_right_leg Kp100_hip=3333\n"
    )
    with pty_console(rig) as term:
        term.write(f"run {seq}\r".encode())
        term.expect(r"\[2/3\] wait 600")
        wire(rig, "hind_right_leg", "Kp100_hip", 2222.0)
        mark = term.mark()
        term.write(key)
        # Safe outputs on the wire (Kp100_hip 0) while the console is still in step 2.
        wait_for(
            "the safe outputs on the wire during the wait",
            lambda: leg_value(rig) == 0.0 and "[3/3]" not in term.text(),
            20,
        )
        wait_for("the node's panic state", lambda: panicked(rig), 20)
        term.expect(r"sequence interrupted at step 2 \(panic\)", since=mark)
        term.expect(r"PANIC: safe outputs on the wire.*type 'clear'", since=mark)
        term.write(b"clear\r")  # the console takes commands again
        term.expect("outputs stay at their safe values", since=mark)
        # The clear restarts nothing: 2222 does not come back (and step 3 never ran).
        wire(rig, "hind_right_leg", "Kp100_hip", 0.0)
        term.write(b"quit\r")
        assert term.wait() == 0
    assert "[3/3]" not in term.text()


def test_ctrl_c_stops_the_running_command_not_the_console(rig: RosRig, tmp_path: Path) -> None:
    commanded(rig, 1212)
    with pty_console(rig) as term:
        term.write(b"wait 600\r")
        term.expect(r"\[running: wait 600")
        term.write(b"layout hind_right_leg\r")  # busy: refused, put back on the line
        term.expect("busy: 'wait 600' is running")
        term.write(b"\x03")
        term.expect(r"interrupted \(Ctrl-C\)")
        term.write(b"\r")  # the refused line, back on the prompt, now runs
        term.expect(r"hind_right_leg \(position \d")
        assert leg_value(rig) == 1212.0 and not panicked(rig)  # outputs as commanded
        term.write(b"quit\r")
        assert term.wait() == 0


@pytest.mark.parametrize("bracketed", [False, True], ids=["typed", "bracketed"])
def test_a_100k_paste_is_refused_and_panic_still_acts(rig: RosRig, bracketed: bool) -> None:
    commanded(rig, 1313)
    with pty_console(rig) as term:
        paste = b"set hind_right_leg Kp100_hip=4444 " + b"x" * 100_000
        if bracketed:
            paste = b"\x1b[200~" + paste + b"\x1b[201~"
        mark = term.mark()
        term.write(paste + b"\r" + CTRL_P)
        wait_for("the panic after the paste", lambda: leg_value(rig) == 0.0, 20)
        term.expect(r"(line|paste) refused: longer than 1024 bytes", since=mark)
        wait_for("the node's panic state", lambda: panicked(rig), 20)
        term.write(b"clear\r")
        term.expect("panic cleared", since=mark)
        # The pasted write never ran, and the clear does not bring 1313 back.
        wire(rig, "hind_right_leg", "Kp100_hip", 0.0)
        term.write(b"quit\r")
        assert term.wait() == 0


def test_command_lines_on_a_terminal_still_take_the_panic_key(rig: RosRig) -> None:
    """`console -c ...` on a terminal reads the keys while its lines run: Ctrl-P panics, stops
    the running line and the run (exit code 1); the lines after it never run."""
    commanded(rig, 1515)
    env = dict(rig.env, PROMPT_TOOLKIT_NO_CPR="1")
    argv = [sys.executable, "-m", "ether_ros.cli.main", "console"]
    with Pty([*argv, "-c", "wait 600", "-c", "set hind_right_leg Kp100_hip=3535"], env=env) as term:
        term.expect(r"\[running: wait 600", timeout=60)
        term.write(CTRL_P)
        wait_for("the safe outputs on the wire", lambda: leg_value(rig) == 0.0, 20)
        term.expect(r"interrupted \(panic\)")
        assert term.wait() == 1
    assert rig.client.command("clear_panic")[0]
    # The second line never ran (not 3535), and the clear does not bring 1515 back.
    wire(rig, "hind_right_leg", "Kp100_hip", 0.0)


def test_step_mode_runs_a_step_only_on_an_explicit_yes(rig: RosRig, tmp_path: Path) -> None:
    commanded(rig, 1414)
    seq = tmp_path / "steps.yaml"
    seq.write_text(
        "steps:\n  - set hind_right_leg Kp100_hip=2424\n  - set hind_right_leg Kp100_hip=2525\n"
    )
    with pty_console(rig) as term:
        term.write(f"run {seq} step\r".encode())
        term.expect(r"\[1/2\] set hind_right_leg Kp100_hip=2424 — run it\?")
        mark = term.mark()
        term.write(b"maybe\r")
        term.expect("answer y", since=mark)
        term.write(b"\r")  # Enter alone is no yes either
        term.expect("answer y", since=term.mark())
        term.write(b"y\r")
        wire(rig, "hind_right_leg", "Kp100_hip", 2424.0)
        term.expect(r"\[2/2\] set hind_right_leg Kp100_hip=2525 — run it\?")
        term.write(b"no\r")
        term.expect("sequence stopped before step 2")
        term.write(b"quit\r")
        assert term.wait() == 0
    assert leg_value(rig) == 2424.0  # step 2 never ran


def test_panic_command_from_stdin_names_the_console_command_to_clear_it(rig: RosRig) -> None:
    r = console(rig, stdin="panic\nclear\n")  # commands from stdin
    assert r.returncode == 0, r.stdout + r.stderr
    assert "PANIC: safe outputs on the wire until the panic is cleared" in r.stdout
    assert "type 'clear'" in r.stdout and "clear_panic" not in r.stdout
    assert "panic cleared" in r.stdout


def test_the_console_takes_the_lease_over_and_panics_without_it(rig: RosRig) -> None:
    """The control lease (config/laelaps.yaml has it on) held by another client, here the
    test's own: the console's writes are refused naming the holder, its panic is accepted all
    the same (panic is anyone's), and ``lease take`` makes the console the holder."""
    ok, message = rig.client.acquire_lease(takeover=True)
    assert ok, message
    holder = rig.client.node.get_fully_qualified_name()
    assert rig.client.write("front_right_leg", "Kp100_knee", 2424)[0]
    wire(rig, "front_right_leg", "Kp100_knee", 2424.0)

    def run(*args: str) -> subprocess.CompletedProcess[str]:
        return subprocess.run(
            [sys.executable, "-m", "ether_ros.cli.main", "console", *args],
            input="", env=rig.env, capture_output=True, text=True, timeout=120, check=False,
        )  # fmt: skip

    r = run("-c", "set front_right_leg Kp100_knee=2525")
    assert r.returncode != 0
    assert f"held by '{holder}'" in r.stdout + r.stderr
    assert rig.client.latest.outputs["front_right_leg"]["Kp100_knee"] == 2424.0

    r = run("-c", "panic")  # without the lease
    assert r.returncode == 0, r.stdout + r.stderr
    wire(rig, "front_right_leg", "Kp100_knee", 0.0)  # the safe outputs
    ok, message = rig.client.command("clear_panic")  # the holder clears it
    assert ok, message
    wire(rig, "front_right_leg", "Kp100_knee", 0.0)  # the clear restarts nothing

    r = run("-c", "lease take", "-c", "set front_right_leg Kp100_knee=2626", "-c", "lease")
    assert r.returncode == 0, r.stdout + r.stderr
    assert f"taken over from '{holder}'" in r.stdout
    assert "(this console)" in r.stdout
    wire(rig, "front_right_leg", "Kp100_knee", 2626.0)
    # The console gave the lease back as it ended; the test's client takes it again.
    ok, message = rig.client.acquire_lease(takeover=True)
    assert ok, message


def test_states_tell_the_truth_after_start_and_when_the_node_is_gone(rig: RosRig) -> None:
    """Right after `start` the slaves are shown in OP (not the INIT of the report before the
    start); with the node dead, its slaves are not shown at all, and it is said to be gone.
    Runs last in this module: it kills the node (and starts it again)."""
    printed: list[str] = []
    with Console(rig.client, out=printed.append) as con:
        assert run_lines(con, ["stop", "start", "states"]) == 0, printed
        shown = {line.split()[0]: line.split()[1] for line in printed if "_leg " in line}
        assert shown == dict.fromkeys(
            ("hind_right_leg", "hind_left_leg", "front_left_leg", "front_right_leg"), "OP"
        )
        assert rig.node_proc is not None
        rig.node_proc.kill()  # a crash: no goodbye on DDS
        rig.node_proc.wait(10)
        printed.clear()
        assert run_lines(con, ["states"]) == 1
        assert printed[0].startswith("node /ether_comm: gone")
        assert "slave states unknown" in printed[1]
        assert not any(" OP" in line or "_leg" in line for line in printed)
        printed.clear()
        # The last report is older than two periods by now.
        wait_for(
            "the diagnostics to age",
            lambda: not rig.client.latest.arrivals.fresh("diagnostics"),
            20,
        )
        assert run_lines(con, ["stats"]) == 1  # the last values, said to be stale
        assert "STALE" in printed[0] and "the node is gone or stalled" in printed[0]
        printed.clear()
        run_lines(con, ["get hind_right_leg Kp100_hip"])
        assert "STALE" in printed[1], printed
    rig.node_proc = None
    rig.start_node()
    assert rig.client.wait_for_node(timeout=60) == "active"
