"""Slave groups at run time: each group's share of the engine's per-frame statistics.

The plan builder (``plan.py``) gives every group its own frames; the engine counts per frame
(``stats()["frames"]``: sent, lost, late, wkc_errors, last_wkc, rtt). A group's statistics are
the sums over its frames, and its working counter is good when every frame's last one matches
the plan. The supervisor reports working-counter trouble per group from these, so a group whose
slaves are lost is named alone and does not hide the others' state.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from ether_ros.master.plan import ImageLayout

#: Per-frame counters summed into a group's.
FRAME_COUNTERS = ("sent", "lost", "late", "wkc_errors", "watchdog_trips")


@dataclass(frozen=True)
class GroupStats:
    name: str
    every: int
    cycle_ns: int
    slaves: tuple[str, ...]
    frames: tuple[int, ...]
    expected_wkc: int
    last_wkc: int
    sent: int
    lost: int
    late: int
    wkc_errors: int
    #: Trips of the group's own watchdog (summed over its frames).
    watchdog_trips: int = 0

    @property
    def wkc_ok(self) -> bool:
        return self.last_wkc == self.expected_wkc

    def as_dict(self) -> dict[str, Any]:
        d = dict(self.__dict__)
        d["slaves"] = list(self.slaves)
        d["frames"] = list(self.frames)
        return d


def group_stats(
    layout: ImageLayout, engine_stats: dict[str, Any], cycle_ns: int
) -> list[GroupStats]:
    """Every group's statistics from the engine's per-frame ones (zeros before the first run)."""
    frames = engine_stats.get("frames") or []
    out = []
    for g in layout.groups:
        mine = [frames[k] for k in g.frames if k < len(frames)]
        totals = {c: sum(int(f.get(c, 0)) for f in mine) for c in FRAME_COUNTERS}
        out.append(
            GroupStats(
                name=g.name,
                every=g.every,
                cycle_ns=g.every * cycle_ns,
                slaves=g.slaves,
                frames=g.frames,
                expected_wkc=layout.group_wkc(g.name),
                last_wkc=sum(int(f.get("last_wkc", 0)) for f in mine),
                **totals,
            )
        )
    return out
