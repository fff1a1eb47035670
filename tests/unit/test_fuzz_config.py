"""The bus configuration boundary under hostile and clumsy input (issue 19).

The mutant corpus of the shipped configurations (``ether_ros.testing.mutants``, seed 1) gives
no traceback, no hang, and every nonsense value refused naming its field; files that are not
files (FIFO, ``/dev/urandom``) and YAML that would grow without bound (alias bombs, 5000-digit
integers, deep nesting) are refused at once; and each case the issue lists has a test of its
own. A hypothesis property puts random values at random places of a configuration.
"""

from __future__ import annotations

import math
import os
import threading
from pathlib import Path
from typing import Any

import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from ether_ros.config import load_bus_config
from ether_ros.config.bus import check_node_name
from ether_ros.config.yamlsrc import MAX_YAML_BYTES
from ether_ros.errors import ConfigError
from ether_ros.testing import fuzzing, mutants

REPO = Path(__file__).resolve().parents[2]
LAELAPS = REPO / "config" / "laelaps.yaml"
ARM = REPO / "config" / "arm6.yaml"


def base(config: Path = LAELAPS) -> dict[str, Any]:
    data = yaml.safe_load(config.read_text())
    data["esi"] = [str(REPO / "devices")]
    return data


def write(tmp_path: Path, data: Any, name: str = "bus.yaml") -> Path:
    p = tmp_path / name
    p.write_text(yaml.safe_dump(data, sort_keys=False, allow_unicode=True))
    return p


def refused(path: Path) -> ConfigError:
    with pytest.raises(ConfigError) as err:
        load_bus_config(path)
    return err.value


# ------------------------------------------------------------------------- the mutant corpus


#: Keys mutated per robot configuration here (seconds). ``make fuzz`` runs the corpus at the
#: issue's size and more: every shipped configuration, 8 and 48 keys each, three seeds.
CORPUS_KEYS = int(os.environ.get("FUZZ_CORPUS_KEYS", "6"))


def test_the_config_mutant_corpus_gives_no_traceback_no_hang_and_names_each_field() -> None:
    # The two robot configurations carry every kind of field (ROS node, joints with scales,
    # CiA 402 axes with limits); the text mutants (alias bomb, 5000 digits, NUL, deep
    # nesting, tags, cuts, flipped bits) come with each file.
    files = [LAELAPS, ARM]
    corpus = mutants.config_mutants(seed=1, leaves_per_file=CORPUS_KEYS, files=files)
    kinds = {m.name.rsplit("=", 1)[-1] for m in corpus} | {m.name.split(": ")[-1] for m in corpus}
    for kind in ("true for a number", "NaN", "a NUL inside", "alias bomb", "a 5000-digit integer"):
        assert kind in kinds, f"the corpus holds no '{kind}' mutant"
    outcomes = fuzzing.run_mutants(corpus, "ether_ros.testing.fuzzing:load_config")
    verdict = fuzzing.verdicts(outcomes)
    assert verdict.clean, verdict.summary()
    assert verdict.counts["nonsense"] > 50
    assert verdict.counts.get("accepted", 0) > 0, "plausible mutants are still accepted"


def test_the_fuzz_runner_reports_hangs_and_tracebacks() -> None:
    """The harness itself: a target that hangs, one that raises something foreign and one that
    eats memory are told apart (so a clean verdict means something)."""
    cases = [("hang", b"hang"), ("raise", b"raise"), ("memory", b"memory"), ("ok", b"ok")]
    corpus = [mutants.Mutant(name, data) for name, data in cases]
    outcomes = fuzzing.run_mutants(corpus, "fuzz_targets:misbehave", timeout_s=8, memory=1024**3)
    kinds = [o.kind for o in outcomes]
    assert kinds == ["hang", "traceback", "traceback", "accepted"], [
        (o.kind, o.detail[-200:]) for o in outcomes
    ]
    assert "MemoryError" in outcomes[2].detail


# ------------------------------------------------------------------------------ not a file


def test_a_fifo_is_refused_without_waiting_for_a_writer(tmp_path: Path) -> None:
    fifo = tmp_path / "bus.yaml"
    os.mkfifo(fifo)
    result: list[BaseException] = []
    t = threading.Thread(target=lambda: result.append(refused(fifo)), daemon=True)
    t.start()
    t.join(timeout=30)
    assert not t.is_alive(), "loading a FIFO hangs"
    assert "not a regular file" in str(result[0])


@pytest.mark.parametrize(
    ("device", "words"),
    [
        ("/dev/urandom", "not a regular file"),
        ("/dev/zero", "not a regular file"),
        ("/proc/self/mem", "cannot read the bus configuration file"),
    ],
)
def test_devices_are_refused_before_anything_is_read(
    device: str, words: str, tmp_path: Path
) -> None:
    link = tmp_path / "bus.yaml"
    link.symlink_to(device)
    for path in (Path(device), link):
        assert words in str(refused(path))


def test_a_directory_and_an_oversized_file_are_refused(tmp_path: Path) -> None:
    assert "a directory" in str(refused(tmp_path))
    big = tmp_path / "big.yaml"
    big.write_bytes(b"# " + b"x" * MAX_YAML_BYTES + b"\n")
    assert "longer than a bus configuration file may be" in str(refused(big))


def test_a_name_with_a_nul_is_refused(tmp_path: Path) -> None:
    err = refused(Path(str(tmp_path / "bus.yaml") + "\0x"))
    assert "not a usable file name" in str(err)


# ---------------------------------------------------------------------- YAML that grows


def test_an_alias_bomb_is_refused_quickly(tmp_path: Path) -> None:
    text = mutants._alias_bomb(9).decode() + LAELAPS.read_text()
    p = tmp_path / "bomb.yaml"
    p.write_text(text)
    err = refused(p)
    assert "values (aliases?)" in str(err) or "aliases" in str(err)


def test_a_recursive_alias_and_deep_nesting_are_refused(tmp_path: Path) -> None:
    p = tmp_path / "loop.yaml"
    p.write_text("a: &a [*a]\n")
    assert "nested deeper than" in str(refused(p))
    p.write_text("a: " + "[" * 5000 + "]" * 5000 + "\n")
    err = refused(p)
    assert err.line == 1 and "nested deeper than 32 levels" in str(err)


def test_a_5000_digit_integer_is_refused_naming_its_line(tmp_path: Path) -> None:
    p = tmp_path / "big.yaml"
    p.write_text(LAELAPS.read_text().replace("cycle_us: 400", "cycle_us: " + "9" * 5000))
    err = refused(p)
    line = 1 + LAELAPS.read_text().splitlines().index(
        next(ln for ln in LAELAPS.read_text().splitlines() if "cycle_us: 400" in ln)
    )
    assert err.line == line and "4096" in str(err)
    p.write_text(LAELAPS.read_text().replace("cycle_us: 400", "cycle_us: " + "9" * 4000))
    err = refused(p)
    assert err.field == "bus.cycle_us" and "wider than 64 bits" in str(err)
    assert len(str(err)) < 300, "the value is named, not echoed"


def test_nul_bytes_and_escapes_are_refused(tmp_path: Path) -> None:
    p = tmp_path / "nul.yaml"
    p.write_bytes(LAELAPS.read_bytes().replace(b"name: laelaps_ii", b"name: lael\0aps"))
    assert "invalid YAML" in str(refused(p))
    data = base()
    data["bus"]["interface"] = "eth0\0junk"
    err = refused(write(tmp_path, data))
    assert err.field == "bus.interface" and "control character" in str(err)


@pytest.mark.parametrize(
    "tag",
    [
        "!!python/object/apply:os.system [ls]",
        "!!binary aGVsbG8=",
        "!!set {a, b}",
        "!!timestamp 2001-12-14",
    ],
)
def test_tags_other_than_plain_values_are_refused(tag: str, tmp_path: Path) -> None:
    p = tmp_path / "tag.yaml"
    p.write_text(LAELAPS.read_text().replace("name: laelaps_ii", f"name: {tag}"))
    err = refused(p)
    assert err.line == 5, err


# -------------------------------------------------------------------- nonsense values (Why)


def put(data: dict[str, Any], path: tuple[Any, ...], value: Any) -> dict[str, Any]:
    node: Any = data
    for key in path[:-1]:
        node = node[key]
    node[path[-1]] = value
    return data


@pytest.mark.parametrize(
    ("path", "value", "words"),
    [
        # booleans are never numbers, numbers never booleans
        (("bus", "cycle_us"), True, "an integer is expected here, not true/false"),
        (("bus", "dc", "sync0_shift_us"), False, "a number is expected here, not true/false"),
        (("ros", "raw_decimation"), True, "not true/false"),
        (("slaves", 0, "sim", "drift_ppm"), True, "not true/false"),
        (("bus", "realtime", "lock_memory"), 1, "true or false is expected here"),
        (("slaves", 0, "lrw"), "yes", "true or false is expected here"),
        # NaN, infinity and 0 are no scale
        (("slaves", 0, "joints", 0, "position_scale"), math.nan, "finite number"),
        (("slaves", 0, "joints", 0, "velocity_scale"), math.inf, "finite number"),
        (("slaves", 0, "joints", 0, "effort_scale"), 0.0, "must not be 0"),
        (("slaves", 0, "joints", 0, "position_offset"), -math.inf, "finite number"),
        (("bus", "dc", "sync0_shift_us"), math.nan, "finite number"),
        # ROS periods and rates whose nanoseconds overflow int64
        (("ros", "snapshot_period_ms"), 2**62, "less than or equal to 3600000"),
        (("ros", "decoded_decimation"), 2**62, "less than or equal to 1000000"),
        # ROS namespaces: the grammar rcl enforces, without its traceback
        (("ros", "namespace"), "/1robot", "not starting with a digit"),
        (("ros", "namespace"), "/a//b", "an empty part"),
        (("ros", "namespace"), "robot/", "an empty part"),
        (("ros", "namespace"), "/ro bot", "is not a ROS name"),
        (("ros", "namespace"), "/robot\0junk", "control character"),
        (("ros", "namespace"), "/" + "a" * 300, "longer than 200"),
        # names and text
        (("slaves", 0, "name"), "hind right", "should match pattern"),
        (("slaves", 0, "device"), "Laelaps\u202eII", "control or format character"),
        (("slaves", 0, "joints", 0, "position"), "x" * 300, "at most 255 characters"),
        (("bus", "interface"), "eth/0", "not a network interface name"),
        (("bus", "interface"), "e" * 16, "1..15 characters"),
        (("esi", 0), "dev\x1bices", "control character"),
        (("slaves", 0, "pdo_assign"), {"rx": [0x1_0000]}, "less than or equal to 65535"),
        (("slaves", 0, "vendor_id"), "0x" + "f" * 30, "not an integer"),
    ],
)
def test_nonsense_is_refused_naming_the_field(
    path: tuple[Any, ...], value: Any, words: str, tmp_path: Path
) -> None:
    data = put(base(), path, value)
    err = refused(write(tmp_path, data))
    field = ".".join(f"[{p}]" if isinstance(p, int) else p for p in path).replace(".[", "[")
    assert err.field is not None and err.field.startswith(field), (err.field, str(err))
    assert words in str(err), str(err)
    assert err.line is not None and err.file is not None


def test_a_namespace_is_normalised_as_rcl_does(tmp_path: Path) -> None:
    for given_ns, kept in [
        ("robot", "/robot"),
        ("/robot/legs", "/robot/legs"),
        ("", ""),
        ("/", "/"),
    ]:
        cfg = load_bus_config(write(tmp_path, put(base(), ("ros", "namespace"), given_ns)))
        assert cfg.ros.namespace == kept


def test_axis_limits_may_be_infinite_but_never_nan(tmp_path: Path) -> None:
    data = base(ARM)
    put(data, ("slaves", 0, "axes", 0, "velocity_limit"), math.inf)
    put(data, ("slaves", 0, "axes", 0, "position_limits"), [-math.inf, math.inf])
    load_bus_config(write(tmp_path, data))
    put(data, ("slaves", 0, "axes", 0, "velocity_limit"), math.nan)
    err = refused(write(tmp_path, data))
    assert err.field == "slaves[0].axes[0].velocity_limit"


def test_node_names_from_the_command_line_are_checked_like_the_file() -> None:
    assert check_node_name("ether_comm") == "ether_comm"
    for bad in ["", "1node", "no de", "node\0x", "a" * 64]:
        with pytest.raises(ConfigError) as err:
            check_node_name(bad)
        assert err.value.field == "ros.node_name"


def test_an_interface_override_is_checked(tmp_path: Path) -> None:
    p = write(tmp_path, base())
    for bad in ["", "eth 0", "e" * 16, "..", "eth0\0"]:
        with pytest.raises(ConfigError) as err:
            load_bus_config(p, interface=bad)
        assert err.value.field == "interface"
    assert load_bus_config(p, interface="veth-a.1").bus.interface == "veth-a.1"


# -------------------------------------------------------------------------- random values

_LEAVES = [p for p, _ in mutants._leaves(base()) if p]
_VALUES = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(min_value=-(2**80), max_value=2**80),
    st.floats(allow_nan=True, allow_infinity=True),
    st.text(max_size=40),
    st.lists(st.integers(), max_size=3),
    st.dictionaries(st.text(max_size=5), st.integers(), max_size=2),
)


@settings(
    max_examples=int(os.environ.get("FUZZ_EXAMPLES", "50")),
    derandomize=True,
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture],
)
@given(leaf=st.sampled_from(_LEAVES), value=_VALUES)
def test_any_value_anywhere_is_taken_or_refused_cleanly(
    leaf: tuple[Any, ...], value: Any, tmp_path: Path
) -> None:
    data = mutants._replaced(base(), leaf, value)
    p = write(tmp_path, data, "random.yaml")
    try:
        load_bus_config(p)
    except ConfigError as err:
        assert err.file is not None and str(err).startswith(str(p))
