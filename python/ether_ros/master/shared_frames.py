"""Work of many slaves at once, their datagrams sharing frames (as IgH's master FSMs do: one
frame per round carries the datagrams of every slave's state machine).

The queue itself is the bus's acyclic worker (``worker.py``); this module keeps the two entry
points the bring-up code and its tests had before the worker existed: ``SharedFrames`` (a
worker for a fixed number of parallel users) and ``run_in_parallel`` (one thread per item over
the worker of ``dg``, the first failure raised once all are done).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import TypeVar

from ether_ros.master.datagrams import DatagramService, Transport
from ether_ros.master.worker import LINGER_S, AcyclicWorker
from ether_ros.master.worker import run_in_parallel as _run_each

T = TypeVar("T")

__all__ = ["LINGER_S", "SharedFrames", "run_in_parallel", "worker_of"]


class SharedFrames(AcyclicWorker):
    """An acyclic worker whose rounds wait for ``workers`` parallel users; ``leave`` when one
    is done."""

    def __init__(self, transport: Transport, workers: int) -> None:
        super().__init__(transport)
        self._parallel = workers

    @property
    def frames(self) -> int:
        return self.stats.frames

    def leave(self) -> None:
        with self._cond:
            self._parallel -= 1
            self._cond.notify_all()


def worker_of(dg: DatagramService) -> AcyclicWorker:
    """The acyclic worker under ``dg`` (a new one when ``dg`` runs straight on a transport)."""
    transport = dg.transport
    if isinstance(transport, AcyclicWorker):
        return transport
    return AcyclicWorker(transport, timeout_us=dg.timeout_us, retries=dg.retries)


def run_in_parallel(
    dg: DatagramService, items: Sequence[T], work: Callable[[DatagramService, T], None]
) -> None:
    """``work(own_dg, item)`` for every item, each in its own thread, their datagrams sharing
    frames; the first failure (in ``items`` order) is raised once all are done."""
    errors = _run_each(worker_of(dg), items, work)
    first = next((e for e in errors if e is not None), None)
    if first is not None:
        raise first
