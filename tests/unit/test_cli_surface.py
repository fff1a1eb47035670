"""One command surface: every (sub)command explains itself in --help with examples, takes -i
wherever it takes --interface, shows its own usage on a usage error, ends quietly when its
reader goes away, and refuses an interface that carries an IP address unless told."""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
from pathlib import Path

import pytest

from ether_ros.cli.common import check_interface, interface_addresses, resolve_interface
from ether_ros.cli.inspect_cmds import graph_format, render_graph
from ether_ros.cli.main import build_parser, main
from ether_ros.errors import ConfigError, EtherRosError

# Commands that take --interface without sending EtherCAT frames on it.
NOT_OPENING = {"rt check", "rt setup", "sim-fault"}


def _parsers(parser: argparse.ArgumentParser, path: str = "") -> dict[str, argparse.ArgumentParser]:
    """Every (sub)command parser of the tree, by its words (``"rt check"``), inner ones too."""
    found: dict[str, argparse.ArgumentParser] = {path.strip(): parser} if path else {}
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, child in action.choices.items():
                found.update(_parsers(child, f"{path} {name}"))
    return found


COMMANDS = _parsers(build_parser())


def test_the_tree_is_walked() -> None:
    assert {"run", "sim", "sim-fault drop", "rt check", "experiment trot", "graph", "top"} <= set(
        COMMANDS
    )


@pytest.mark.parametrize("name", sorted(COMMANDS))
def test_every_command_has_a_description_and_examples(name: str) -> None:
    parser = COMMANDS[name]
    assert parser.description and len(parser.description) > 20, f"ether-ros {name}: no description"
    text = parser.format_help()
    assert "\nexamples:\n" in text, f"ether-ros {name} --help shows no examples"
    examples = text.split("\nexamples:\n", 1)[1].splitlines()
    top = name.split()[0]
    assert any(line.strip().startswith(f"ether-ros {top}") for line in examples), (
        f"ether-ros {name}: no example runs the command"
    )
    assert "``" not in text, f"ether-ros {name} --help shows raw markup"


@pytest.mark.parametrize("name", sorted(n for n, p in COMMANDS.items() if "--interface" in
                                        p._option_string_actions))  # fmt: skip
def test_short_interface_option_wherever_the_long_one_is(name: str) -> None:
    options = COMMANDS[name]._option_string_actions
    assert options.get("-i") is options["--interface"], f"ether-ros {name}: no -i"
    opens = not any(name == n or name.startswith(n + " ") for n in NOT_OPENING)
    assert ("--allow-ip-interface" in options) == opens, name


def test_a_usage_error_shows_the_subcommands_usage(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exit_:
        main(["record", "config/laelaps.yaml", "-o", "x.mcap", "--no-such-option"])
    assert exit_.value.code == 2
    err = capsys.readouterr().err
    assert "usage: ether-ros record" in err and "unrecognized arguments: --no-such-option" in err
    with pytest.raises(SystemExit):
        main(["rt", "check", "--bogus"])
    assert "usage: ether-ros rt check" in capsys.readouterr().err


def test_an_interface_with_an_ip_address_is_refused_unless_allowed() -> None:
    assert "127.0.0.1" in interface_addresses("lo")
    with pytest.raises(ConfigError) as refused:
        check_interface("lo", allow_ip=False, command="slaves")
    message = str(refused.value)
    assert "127.0.0.1" in message and "--allow-ip-interface" in message
    assert "ether-ros slaves" in message
    check_interface("lo", allow_ip=True, command="slaves")
    assert interface_addresses("nosuchif0") == []  # opening it says what is wrong


def test_the_ip_check_runs_through_the_command_line(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["slaves", "-i", "lo"]) == 2
    assert "--allow-ip-interface" in capsys.readouterr().err


def test_no_interface_names_the_option_and_the_command() -> None:
    args = argparse.Namespace(interface=None)
    with pytest.raises(ConfigError, match=r"'ether-ros record' -i/--interface and cfg.yaml"):
        resolve_interface(args, None, "record", "cfg.yaml")
    assert resolve_interface(argparse.Namespace(interface=None), "nosuchif0", "run") == "nosuchif0"


def test_shipped_configs_name_no_interface() -> None:
    from ether_ros.config import load_bus_config

    root = os.path.join(os.path.dirname(__file__), "..", "..", "config")
    import yaml

    names = sorted(
        f
        for f in os.listdir(root)
        if f.endswith(".yaml") and "bus" in (yaml.safe_load(Path(root, f).read_text()) or {})
    )  # bus configurations (config/ holds other YAML too, e.g. MoveIt's controllers)
    assert "laelaps.yaml" in names
    for name in names:
        assert load_bus_config(os.path.join(root, name)).bus.interface is None, name


def test_graph_formats_and_rendering() -> None:
    assert graph_format(None, None) == "dot"
    assert graph_format(None, "bus.PNG") == "png"
    assert graph_format(None, "bus.svg") == "svg"
    assert graph_format("svg", "bus.dot") == "svg"
    assert graph_format(None, "bus.txt") == "dot"
    dot = 'digraph bus { "master" -> "slave 0"; }'
    assert render_graph(dot, "png").startswith(b"\x89PNG\r\n\x1a\n")
    assert b"<svg" in render_graph(dot, "svg")
    with pytest.raises(EtherRosError, match="dot -Tpng failed"):
        render_graph("this is not a graph {", "png")


def _into_closed_pipe(words: list[str]) -> tuple[int, str]:
    """``main(words)`` in this process with stdout a pipe whose reader is already gone."""
    import contextlib
    import io

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


@pytest.mark.parametrize("name", sorted(COMMANDS))
def test_help_into_a_closed_pipe_ends_quietly(name: str) -> None:
    """`ether-ros ... --help | head -0` for every (sub)command: no traceback, the exit status
    of a process ended by SIGPIPE. (Each command's real output into a closed pipe, on the
    simulator: tests/acceptance/test_cli_pipes.py.)"""
    code, err = _into_closed_pipe([*name.split(), "--help"])
    assert "Traceback" not in err and "BrokenPipeError" not in err, f"{name}: {err}"
    assert code == 141, f"{name}: exit {code}: {err}"


def test_a_process_whose_reader_goes_away_prints_no_traceback() -> None:
    """The same as its own process: the interpreter's last flush must not complain either."""
    read, write = os.pipe()
    os.close(read)
    try:
        done = subprocess.run(
            [sys.executable, "-m", "ether_ros.cli.main", "rt", "check", "--json"],
            stdout=write,
            stderr=subprocess.PIPE,
            timeout=120,
            check=False,
        )
    finally:
        os.close(write)
    err = done.stderr.decode()
    assert "Traceback" not in err and "BrokenPipeError" not in err and "Exception" not in err, err
    assert done.returncode == 141
