"""`ether-ros COMMAND | head` ends quietly: every subcommand's real output, on the simulated
bus, written into a pipe whose reader has already gone, ends without a traceback and with the
exit status of a process ended by SIGPIPE (141). Every subcommand's --help does the same in
tests/unit/test_cli_surface.py; the commands that only run with a terminal (top) or a node to
talk to (console) or that build their own network (demo) are covered there."""

from __future__ import annotations

import contextlib
import io
import os
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from ether_ros.cli.main import BROKEN_PIPE_EXIT, main
from ether_ros.sim.proof import SimProcess
from ether_ros.testing.netns import VethPair
from user_commands import LAELAPS

pytestmark = pytest.mark.netns


@pytest.fixture(scope="module")
def bus(veth_allowed: bool) -> Iterator[tuple[VethPair, SimProcess]]:
    if not veth_allowed:
        pytest.fail("creating a network namespace needs root; run the tests as root")
    with VethPair.create(netns=True) as veth, SimProcess(LAELAPS, veth.slave, veth.netns) as sim:
        yield veth, sim


def into_closed_pipe(words: list[str]) -> tuple[int, str]:
    """``main(words)`` in this process, stdout a pipe whose reader is gone."""
    read, write = os.pipe()
    os.close(read)
    err = io.StringIO()
    with (
        open(write, "w") as stdout,
        contextlib.redirect_stdout(stdout),
        contextlib.redirect_stderr(err),
    ):
        try:
            code = main(words)
        except SystemExit as exit_:
            code = int(exit_.code or 0)
    return code, err.getvalue()


def process_into_closed_pipe(words: list[str]) -> subprocess.CompletedProcess[bytes]:
    """``ether-ros WORDS`` as its own process, stdout a pipe whose reader is gone."""
    read, write = os.pipe()
    os.close(read)
    try:
        return subprocess.run(
            [sys.executable, "-m", "ether_ros.cli.main", *words],
            stdout=write,
            stderr=subprocess.PIPE,
            timeout=300,
            check=False,
        )
    finally:
        os.close(write)


def test_every_bus_command_into_a_closed_pipe(
    bus: tuple[VethPair, SimProcess], tmp_path: Path
) -> None:
    veth, sim = bus
    i = ["-i", veth.master]
    recording = str(tmp_path / "run.mcap")
    commands = [
        ["slaves", *i],
        ["states", *i],
        ["pdos", *i],
        ["sdos", *i, "-p", "0"],
        ["upload", *i, "-p", "0", "0x1018:01"],
        ["download", *i, "-p", "1", "0x7030:03", "0", "-c", str(LAELAPS)],
        ["reg-read", *i, "-p", "0", "0x0130", "2"],
        ["reg-write", *i, "-p", "0", "0x0012", "0000"],  # the station alias register: unused
        ["sii-read", *i, "-p", "0"],
        ["xml", *i, "-p", "0"],
        ["graph", *i],
        ["graph", *i, "--format", "png"],
        ["master", *i, "--probes", "10"],
        ["sim-fault", "--control", str(sim.control), "stats"],
        ["rt", "check", *i],
        ["bench", "cycle", str(LAELAPS), *i, "--seconds", "0.5"],
        ["record", str(LAELAPS), *i, "--seconds", "0.5", "-o", recording],
        ["experiment", "trot", str(LAELAPS), *i, "--transition", "1", "--hold", "0.5"],
        ["plot", recording, "-o", str(tmp_path / "plots"), "--format", "png"],
    ]
    for words in commands:
        code, err = into_closed_pipe(words)
        assert "Traceback" not in err and "BrokenPipeError" not in err, f"{words}: {err}"
        assert code == BROKEN_PIPE_EXIT, f"{words}: exit {code}: {err}"


def test_the_simulator_and_the_node_into_a_closed_pipe(
    bus: tuple[VethPair, SimProcess],
) -> None:
    """Their one line goes nowhere: both end quietly, the node after leaving the bus safe."""
    veth, _sim = bus
    done = process_into_closed_pipe(["run", str(LAELAPS), "-i", veth.master])
    err = done.stderr.decode()
    assert "Traceback" not in err and "BrokenPipeError" not in err, err
    assert done.returncode == BROKEN_PIPE_EXIT, err
    with VethPair.create(netns=True) as other:
        argv = [sys.executable, "-m", "ether_ros.cli.main", "sim", str(LAELAPS),
                "-i", other.slave, "--no-control"]  # fmt: skip
        read, write = os.pipe()
        os.close(read)
        try:
            done = subprocess.run(
                ["ip", "netns", "exec", str(other.netns), *argv],
                stdout=write,
                stderr=subprocess.PIPE,
                timeout=120,
                check=False,
            )
        finally:
            os.close(write)
    err = done.stderr.decode()
    assert "Traceback" not in err and "BrokenPipeError" not in err, err
    assert done.returncode == BROKEN_PIPE_EXIT, err
