"""Bring-up work of many slaves at once, their datagrams sharing frames (as IgH's master FSMs
do: one frame per round carries the datagrams of every slave's state machine).

Each slave's configuration (SDO init over its mailbox, SyncManagers, FMMUs) runs as it always
does — a sequence of blocking ``transact`` calls — but in a worker thread of its own, over a
:class:`SharedFrames` transport. A worker's ``transact`` waits until every worker still at work
is waiting too (or a short linger has passed, e.g. while one sleeps between mailbox polls), and
then one of them sends all their datagrams in as few frames as hold them. With N slaves an SDO
exchange costs the bus the round trips of one slave, not of N.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any, TypeVar

from ether_ros.master.datagrams import DATAGRAM_OVERHEAD, FRAME_PAYLOAD, DatagramService, Transport

T = TypeVar("T")

#: How long a worker's datagrams wait for the other workers' before they go out anyway.
LINGER_S = 0.002


def _size(item: tuple[int, int, bytes | int]) -> int:
    payload = item[2]
    return DATAGRAM_OVERHEAD + (payload if isinstance(payload, int) else len(payload))


@dataclass
class _Request:
    datagrams: list[tuple[int, int, bytes | int]]
    timeout_us: int
    retries: int
    replies: list[Any] | None = None
    error: BaseException | None = None
    done: bool = False
    posted: float = field(default_factory=time.monotonic)


class SharedFrames:
    """A ``Transport`` for several worker threads whose requests go out together."""

    def __init__(self, transport: Transport, workers: int) -> None:
        self.transport = transport
        self.active = workers
        self.frames = 0  # frames sent (for tests and measurements)
        self._pending: list[_Request] = []
        self._cond = threading.Condition()

    def leave(self) -> None:
        """A worker is done: the others no longer wait for its datagrams."""
        with self._cond:
            self.active -= 1
            self._cond.notify_all()

    def transact(
        self, request: Sequence[tuple[int, int, bytes | int]], timeout_us: int = 20_000,
        retries: int = 3,
    ) -> list[Any]:  # fmt: skip
        mine = _Request(list(request), timeout_us, retries)
        with self._cond:
            self._pending.append(mine)
            self._cond.notify_all()
            while not mine.done:
                ready = len(self._pending) >= self.active
                lingered = bool(self._pending) and (
                    time.monotonic() - self._pending[0].posted >= LINGER_S
                )
                if mine in self._pending and (ready or lingered):
                    batch, self._pending = self._pending, []
                    self._cond.release()
                    try:
                        self._send(batch)
                    finally:
                        self._cond.acquire()
                        self._cond.notify_all()
                    continue
                self._cond.wait(LINGER_S / 2)
        if mine.error is not None:
            raise mine.error
        assert mine.replies is not None
        return mine.replies

    def _send(self, batch: list[_Request]) -> None:
        """All requests of ``batch`` in as few frames as hold them (a request never split)."""
        frames: list[list[_Request]] = []
        used = FRAME_PAYLOAD
        for r in batch:
            size = sum(_size(d) for d in r.datagrams)
            if used + size > FRAME_PAYLOAD:
                frames.append([])
                used = 0
            frames[-1].append(r)
            used += size
        for group in frames:
            datagrams = [d for r in group for d in r.datagrams]
            try:
                replies = list(
                    self.transport.transact(
                        datagrams,
                        timeout_us=max(r.timeout_us for r in group),
                        retries=max(r.retries for r in group),
                    )
                )
                self.frames += 1
            except BaseException as exc:  # handed to every worker whose datagrams were in it
                for r in group:
                    r.error, r.done = exc, True
                continue
            for r in group:
                r.replies, replies = replies[: len(r.datagrams)], replies[len(r.datagrams) :]
                r.done = True


def run_in_parallel(
    dg: DatagramService, items: Sequence[T], work: Callable[[DatagramService, T], None]
) -> None:
    """``work(own_dg, item)`` for every item, each in its own thread, their datagrams sharing
    frames; the first failure (in ``items`` order) is raised once all are done."""
    if len(items) <= 1:
        for item in items:
            work(dg, item)
        return
    shared = SharedFrames(dg.transport, len(items))
    errors: list[BaseException | None] = [None] * len(items)

    def run(k: int, item: T) -> None:
        own = DatagramService(shared, timeout_us=dg.timeout_us, retries=dg.retries)
        try:
            work(own, item)
        except BaseException as exc:  # reported by the caller's thread below
            errors[k] = exc
        finally:
            shared.leave()

    threads = [
        threading.Thread(target=run, args=(k, item), name=f"ether_ros-bringup-{k}", daemon=True)
        for k, item in enumerate(items)
    ]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    first = next((e for e in errors if e is not None), None)
    if first is not None:
        raise first
