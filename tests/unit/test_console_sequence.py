"""Sequence files: checked completely (each write against the state the earlier steps leave)
before anything runs; a bad step is named with its number and reason."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from bus_specs import spec_of
from ether_ros.console.commands import CommandError, ConsoleContext, Control, Wait, Write
from ether_ros.console.sequence import find_sequence, load_sequence, parse_sequence
from ether_ros.ros.layout import BusSpec
from ether_ros.testing import mutants


@pytest.fixture(scope="module")
def laelaps() -> BusSpec:
    return spec_of("laelaps.yaml")


def zero_outputs(spec: BusSpec) -> ConsoleContext:
    # What the node reports before anything was commanded: every output 0.
    return ConsoleContext(spec, {s.name: {v.name: 0.0 for v in s.outputs} for s in spec.slaves})


def test_packaged_trot_is_valid_from_all_zero_outputs(laelaps: BusSpec) -> None:
    seq = load_sequence("trot", zero_outputs(laelaps))
    assert seq.path.endswith("trot.yaml")
    writes = [s.command for s in seq.steps if isinstance(s.command, Write)]

    # b goes to 4 cm on every leg before a goes to 5 cm, and both come back to 0 (a first).
    def index_of(variable: str, value: float) -> list[int]:
        return [
            i
            for i, w in enumerate(writes)
            if (w.ops[0].variable, w.ops[0].value) == (variable, value) and len(w.ops) == 4
        ]

    (b_up,), (a_up,) = index_of("b_ellipse100", 4.0), index_of("a_ellipse100", 5.0)
    (a_down,), (b_down,) = index_of("a_ellipse100", 0.0), index_of("b_ellipse100", 0.0)
    assert b_up < a_up < a_down < b_down
    assert {op.slave for op in writes[b_up].ops} == {s.name for s in laelaps.slaves}
    phases = {op.slave: op.value for w in writes for op in w.ops if op.variable == "phase_deg"}
    assert phases == {
        "front_left_leg": 180.0,
        "front_right_leg": 0.0,
        "hind_left_leg": 0.0,
        "hind_right_leg": 180.0,
    }
    assert 15 <= seq.duration_s <= 40


def test_mapping_and_line_steps_and_checked_against_earlier_steps(laelaps: BusSpec) -> None:
    ctx = zero_outputs(laelaps)
    data = {
        "steps": [
            {
                "set": {
                    "target": "front_left_leg",
                    "values": {
                        "x_cntr_traj1000": 0,
                        "y_cntr_traj1000": 599,
                        "a_ellipse100": 0,
                        "b_ellipse100": 0,
                        "traj_freq100": 100,
                        "phase_deg": 0,
                        "FlatnessParam100": 0,
                    },
                }
            },
            "set front_left_leg b_ellipse100=4",
            {"wait": 1},
            "panic",
            {"clear": None},
        ]
    }
    seq = parse_sequence(data, "inline", ctx)
    kinds = [type(s.command) for s in seq.steps]
    assert kinds == [Write, Write, Wait, Control, Control]
    assert seq.duration_s == 1.0


@pytest.mark.parametrize(
    ("data", "reason"),
    [
        ({"steps": ["set all b_ellipse100=4"]}, "step 1: slave"),  # y centre still 0
        ({"steps": [{"wait": 1}, "set front_left_leg nothing=1"]}, "step 2: slave"),
        ({"steps": ["run other.yaml"]}, "not allowed in a sequence"),
        ({"steps": ["quit"]}, "not allowed in a sequence"),
        ({"steps": [{"wait": 1, "set": 2}]}, "one-key mapping"),
        ({"steps": [{"set": {"target": "all"}}]}, "needs a target and at least one value"),
        ({"steps": [{"set": {"target": "all", "values": {"a": [1, 2]}}}]}, "not a single value"),
        ({"steps": []}, "no steps"),
        ({"steps": "wait 1"}, "a list 'steps'"),
        ({"steps": [{"wait": 1}], "loop": True}, "unknown key(s) loop"),
        ({"steps": [{"wait": -1}]}, "non-negative"),
        ({"steps": ["set all 'b_ellipse100=4 sh -c reboot'"]}, "step 1"),
    ],
)
def test_bad_sequences_name_the_step_and_reason(
    laelaps: BusSpec, data: object, reason: str
) -> None:
    with pytest.raises(CommandError) as err:
        parse_sequence(data, "bad.yaml", zero_outputs(laelaps))
    assert reason in str(err.value)
    assert str(err.value).startswith("bad.yaml: ")


def test_unreadable_and_invalid_yaml_files(tmp_path: Path, laelaps: BusSpec) -> None:
    with pytest.raises(CommandError, match="sequence file not found"):
        load_sequence(tmp_path / "missing.yaml", zero_outputs(laelaps))
    bad = tmp_path / "bad.yaml"
    bad.write_text("steps: [unclosed\n")
    with pytest.raises(CommandError, match=r"bad.yaml:2: invalid YAML"):
        load_sequence(bad, zero_outputs(laelaps))
    assert find_sequence(str(bad)) == bad
    # The configuration's bounded loader: a FIFO is refused at once, an alias bomb too.
    fifo = tmp_path / "fifo.yaml"
    os.mkfifo(fifo)
    with pytest.raises(CommandError, match="not a regular file"):
        load_sequence(fifo, zero_outputs(laelaps))
    bomb = tmp_path / "bomb.yaml"
    bomb.write_bytes(mutants._alias_bomb() + b"steps: [wait 1]\n")
    with pytest.raises(CommandError, match="aliases expand to more than"):
        load_sequence(bomb, zero_outputs(laelaps))
