"""The shape of a bus: which slave hangs on which port of which other slave.

Facts (Beckhoff ESC datasheet section I, "Frame processing order", "Loop control"): a frame
entering a slave's port 0 passes its processing unit and leaves through the next port in the
order 0 → 3 → 1 → 2 (ports the chip lacks are skipped); a port without a link is closed and
the frame goes on to the next port internally; what comes back into a port leaves through the
next one, and finally through port 0 back towards the master. So the frame visits the slaves
depth first in that port order, and the auto-increment positions are that visiting order.

Used by the configuration (the expected tree, ``connected_to``), the scan (the tree found on the
wire, from each slave's open ports in DL status 0x0110), distributed clocks (delays per branch),
the graph and the supervisor (what a pulled cable cut off). Positions index everything here.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from ether_ros._native import protocol

# Order in which a slave passes the frame from port to port: the protocol crate's.
PORT_ORDER: tuple[int, ...] = protocol.PORT_ORDER
MASTER = "the master"


@dataclass(frozen=True)
class Link:
    """Where a slave's port 0 is connected: port ``port`` of the slave at position ``parent``,
    or the master (``parent`` None, ``port`` 0)."""

    parent: int | None
    port: int


def forwarding_ports(mask: int) -> list[int]:
    """The ports after port 0 in ``mask`` (bit p = port p), in the order the frame uses them."""
    return protocol.forwarding_ports(mask)


def open_ports(dl_status: int) -> int:
    """Ports with their loop open and communication established, from DL status 0x0110:
    bit p of the result = port p."""
    return protocol.open_ports(dl_status)


def line(count: int) -> list[Link]:
    """The tree of a line: each slave on port 1 of the one before."""
    return [Link(None, 0) if k == 0 else Link(k - 1, 1) for k in range(count)]


def tree_from_ports(masks: Sequence[int]) -> list[Link]:
    """Rebuild the tree from each slave's open ports, in auto-increment order.

    The frame goes depth first: each slave after the first hangs on the next unused open port
    (in port order) of the nearest slave before it that still has one. Raises ``ValueError``
    when the ports cannot carry the slaves (a slave left over with every port used)."""
    links: list[Link] = []
    # (position, its open ports not yet followed), deepest last.
    pending: list[tuple[int, list[int]]] = []
    for pos, mask in enumerate(masks):
        if pos == 0:
            links.append(Link(None, 0))
        else:
            while pending and not pending[-1][1]:
                pending.pop()
            if not pending:
                raise ValueError(
                    f"slave {pos}: no open port is left on the slaves before it to connect it"
                    " (DL status 0x0110 disagrees with the number of slaves)"
                )
            parent, free = pending[-1]
            links.append(Link(parent, free.pop(0)))
        pending.append((pos, forwarding_ports(mask)))
    return links


def children(tree: Sequence[Link], slave: int) -> dict[int, int]:
    """Port → position of the slaves connected to ``slave``'s ports."""
    return {link.port: k for k, link in enumerate(tree) if link.parent == slave}


def used_ports(tree: Sequence[Link], slave: int) -> int:
    """Bit mask of ``slave``'s ports with something on them (port 0 always)."""
    mask = 1
    for link in tree:
        if link.parent == slave:
            mask |= 1 << link.port
    return mask


def visit_order(tree: Sequence[Link]) -> list[int]:
    """Positions in the order a frame visits them (depth first, ports 0 → 3 → 1 → 2); equal to
    ``range(len(tree))`` when ``tree`` is listed in auto-increment order."""
    order: list[int] = []

    def visit(k: int) -> None:
        order.append(k)
        below = children(tree, k)
        for port in PORT_ORDER[1:]:
            if port in below:
                visit(below[port])

    for k, link in enumerate(tree):
        if link.parent is None:
            visit(k)
    return order


def behind(tree: Sequence[Link], slave: int) -> list[int]:
    """``slave`` and every slave behind it (its branch), in visiting order."""
    inside = {slave}
    for k in range(slave + 1, len(tree)):
        parent = tree[k].parent
        if parent is not None and parent in inside:
            inside.add(k)
    return sorted(inside)


def where(link: Link, names: Sequence[str]) -> str:
    """``port 2 of 'coupler'`` (``names`` by position) or ``the master``."""
    if link.parent is None:
        return MASTER
    name = names[link.parent] if link.parent < len(names) else f"slave {link.parent}"
    return f"port {link.port} of '{name}'"


def first_difference(
    expected: Sequence[Link], found: Sequence[Link], names: Sequence[str]
) -> str | None:
    """Where the bus (``found``) and the configuration (``expected``, slave names by position
    in ``names``) first differ, as a message naming the position, or None when they agree."""
    for pos in range(max(len(expected), len(found))):
        if pos >= len(found):
            return (
                f"slave {pos}: config expects '{names[pos]}' on {where(expected[pos], names)},"
                f" the bus has no slave {pos} (only {len(found)} found)"
            )
        if pos >= len(expected):
            return (
                f"slave {pos}: the bus has a slave on {where(found[pos], names)} that the config"
                f" does not list ({len(expected)} configured)"
            )
        if expected[pos] != found[pos]:
            return (
                f"slave {pos}: config expects '{names[pos]}' on {where(expected[pos], names)},"
                f" the bus has it on {where(found[pos], names)}"
            )
    return None


def cut_branches(tree: Sequence[Link], answered: Sequence[bool]) -> list[tuple[int, list[int]]]:
    """Where cables are broken, from which slaves answer (by position): for each slave that
    does not answer while the slave it hangs on does, ``(that slave, the silent slaves of its
    branch)``. A broken cable hides the whole branch behind it, so the cut sits at the first
    silent slave of the branch. (A silent first slave is the master's own link: not listed.)"""
    cuts: list[tuple[int, list[int]]] = []
    for k, link in enumerate(tree):
        if answered[k] or link.parent is None or not answered[link.parent]:
            continue
        cuts.append((k, [b for b in behind(tree, k) if not answered[b]]))
    return cuts
