"""The bus tree: rebuilt from open ports in auto-increment order, the visiting order, the first
difference from a configuration, where a broken cable is, and propagation delays per branch
(numbers worked out by hand from the port times a frame leaves on the tree)."""

from __future__ import annotations

from pathlib import Path

import pytest

from ether_ros.config import load_bus_config
from ether_ros.errors import ConfigError
from ether_ros.master.dc import diff32, tree_delays
from ether_ros.topology import (
    Link,
    behind,
    cut_branches,
    first_difference,
    forwarding_ports,
    line,
    open_ports,
    tree_from_ports,
    visit_order,
)

REPO = Path(__file__).resolve().parents[2]
BRANCHED = REPO / "config" / "branched.yaml"

#   master ─300─ coupler ─1─450─ io_1 ─1─600─ io_2
#                        └2─900─ junction ─3─700─ leg
#                                         ├1─350─ io_3
#                                         └2─800─ io_4
NAMES = ["coupler", "io_1", "io_2", "junction", "leg", "io_3", "io_4"]
TREE = [
    Link(None, 0),
    Link(0, 1),
    Link(1, 1),
    Link(0, 2),
    Link(3, 3),
    Link(3, 1),
    Link(3, 2),
]
# Open ports (bit p = port p) as DL status shows them.
MASKS = [0b0111, 0b0011, 0b0001, 0b1111, 0b0001, 0b0001, 0b0001]


def test_port_order_is_0_3_1_2() -> None:
    assert forwarding_ports(0b1111) == [3, 1, 2]
    assert forwarding_ports(0b0101) == [2]


def test_open_ports_from_dl_status() -> None:
    # Port 0 and 1 open with communication, ports 2 and 3 loop closed.
    assert open_ports(0x0200 | 0x0800 | 0x1000 | 0x4000 | 0x0030) == 0b0011
    # A port with communication but its loop closed is not open.
    assert open_ports(0x0200 | 0x0800 | 0x0400) == 0b0001


def test_tree_from_open_ports_follows_the_depth_first_port_order() -> None:
    assert tree_from_ports(MASKS) == TREE
    assert tree_from_ports([0b11, 0b11, 0b01]) == line(3)
    with pytest.raises(ValueError, match="slave 2: no open port"):
        tree_from_ports([0b11, 0b01, 0b01])


def test_visit_order_and_branches() -> None:
    assert visit_order(TREE) == list(range(7))
    # Listed in the wrong order: a slave on port 1 listed before the one on port 3.
    assert visit_order([Link(None, 0), Link(0, 1), Link(0, 3)]) == [0, 2, 1]
    assert behind(TREE, 3) == [3, 4, 5, 6]
    assert behind(TREE, 1) == [1, 2]


def test_first_difference_names_position_config_and_bus() -> None:
    assert first_difference(TREE, TREE, NAMES) is None
    # io_3 cabled behind the leg instead of on the junction's port 1.
    swapped = [*TREE[:5], Link(4, 1), Link(3, 2)]
    assert first_difference(TREE, swapped, NAMES) == (
        "slave 5: config expects 'io_3' on port 1 of 'junction', the bus has it on port 1 of 'leg'"
    )
    missing = TREE[:6]
    assert first_difference(TREE, missing, NAMES) == (
        "slave 6: config expects 'io_4' on port 2 of 'junction', the bus has no slave 6"
        " (only 6 found)"
    )
    extra = [*TREE, Link(6, 1)]
    assert first_difference(TREE, extra, NAMES) == (
        "slave 7: the bus has a slave on port 1 of 'io_4' that the config does not list"
        " (7 configured)"
    )


def test_a_silent_branch_is_located_at_its_first_slave() -> None:
    answered = [True, True, True, False, False, False, False]
    assert cut_branches(TREE, answered) == [(3, [3, 4, 5, 6])]
    answered = [True, True, True, True, True, False, True]
    assert cut_branches(TREE, answered) == [(5, [5])]
    # Everything silent: the master's own link, not a branch.
    assert cut_branches(TREE, [False] * 7) == []


def _port_times(bases: list[int]) -> dict[int, tuple[int, int, int, int]]:
    """Receive times the tree above latches, frame leaving the master at 0, each slave's
    local clock offset by ``bases[k]`` (32-bit latches, so they may wrap)."""
    arrive = {0: 300, 1: 750, 2: 1350, 3: 3300, 4: 4000, 5: 5050, 6: 6200}
    back = {  # (slave, port) -> time the frame comes back into that port
        (1, 1): 1950,
        (0, 1): 2400,
        (3, 3): 4700,
        (3, 1): 5400,
        (3, 2): 7000,
        (0, 2): 7900,
    }
    out = {}
    for k, base in enumerate(bases):
        t = [arrive[k], back.get((k, 1), 0), back.get((k, 2), 0), back.get((k, 3), 0)]
        out[k] = tuple((base + v) & 0xFFFFFFFF for v in t)
    return out


def test_delays_per_branch_worked_by_hand() -> None:
    # Junction (port 2 of the coupler): the coupler's earlier branch took 2400 − 300 = 2100 ns;
    # its own branch 7900 − 2400 = 5500 ns, of which 7000 − 3300 = 3700 inside the junction's
    # branches: 2100 + (5500 − 3700) / 2 = 3000. io_4 (port 2 of the junction): 3000 +
    # (5400 − 3300) + (7000 − 5400) / 2 = 5900.
    times = _port_times([0xFFFF_F000, 17, 123_456, 9, 0x7FFF_FFFF, 42, 1_000_000])
    assert tree_delays(TREE, times) == {0: 0, 1: 450, 2: 1050, 3: 3000, 4: 3700, 5: 4750, 6: 5900}


def test_delays_in_a_line_are_half_the_loop_differences() -> None:
    hop, n = 700, 4
    times = {}
    for i in range(n):
        t0 = 1000 + i * hop
        times[i] = (t0, t0 + 2 * hop * (n - 1 - i), 0, 0)
    assert tree_delays(line(n), times) == {0: 0, 1: 700, 2: 1400, 3: 2100}
    # A slave without DC in the middle: the next DC slave measures across it.
    del times[2]
    assert tree_delays(line(n), times) == {0: 0, 1: 700, 3: 2100}


def test_delay_latches_wrap_at_32_bits() -> None:
    assert diff32(3, 0xFFFF_FFFE) == 5
    times = {0: (0xFFFF_FF00, 0x0000_0100, 0, 0), 1: (0x10, 0x0, 0, 0)}
    assert tree_delays(line(2), times) == {0: 0, 1: 0x100}


def test_branched_config_gives_the_tree() -> None:
    cfg = load_bus_config(BRANCHED)
    assert cfg.declares_topology
    assert cfg.tree() == TREE
    assert [s.name for s in cfg.by_position()] == NAMES


def _edited(tmp_path: Path, edits: list[tuple[str, str]]) -> Path:
    text = BRANCHED.read_text()
    for old, new in edits:
        assert old in text
        text = text.replace(old, new)
    out = tmp_path / "branched.yaml"
    out.write_text(text.replace("[../devices]", f"[{REPO / 'devices'}]"))
    return out


JUNCTION = "connected_to: {slave: junction, port: %d}"
IO_1 = "connected_to: {slave: io_1, port: 1}"


@pytest.mark.parametrize(
    ("edits", "message"),
    [
        ([(JUNCTION % 1, JUNCTION % 3)], "port 3 of 'junction' is taken by 'leg'"),
        (
            # leg on port 2, io_4 on port 3: the frame reaches io_4 first.
            [(JUNCTION % 2, "@"), (JUNCTION % 3, JUNCTION % 2), ("@", JUNCTION % 3)],
            "the frame reaches 'io_4' (position 6) before 'leg'",
        ),
        ([(IO_1, "connected_to: {slave: io_9, port: 1}")], "no slave by this name"),
        (
            [(IO_1, "connected_to: {slave: io_4, port: 1}")],
            "'io_4' is at position 6, not before this slave",
        ),
        ([(IO_1, "connected_to: {slave: io_1, port: 4}")], "less than or equal to 3"),
    ],
)
def test_bad_topology_in_the_config_is_named(
    tmp_path: Path, edits: list[tuple[str, str]], message: str
) -> None:
    with pytest.raises(ConfigError, match=r"connected_to|position") as err:
        load_bus_config(_edited(tmp_path, edits))
    assert message in str(err.value)
