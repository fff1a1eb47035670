"""The bus's acyclic worker: the one owner of the acyclic datagrams and of every slave's mailbox.

Every acyclic user — bring-up and recovery (one state machine per slave, ``slave_fsm.py``),
SDO/SII/register access from the ``Bus`` API, the ROS node, the console, and the inspection
tools of other processes (``service.py``) — queues its datagrams here (``transact``). A round
sends every request queued by then, of every user and slave, in as few frames as hold them
(IgH's master datagram queue; ethercrab's PDU loop): requests of different slaves share
frames, and since each user has at most one request in a round, a slave that answers slowly
(its mailbox polled round after round) costs the others nothing but a few bytes of a frame.

The worker is a role, not a thread: the user that finds the wire free sends the round for
everyone queued meanwhile ("flat combining"), so a lone user pays no hand-over to another
thread, and while one round is on the wire the next one fills. While several users work in
parallel (``parallel``: bring-up of many slaves) a round waits for all of them, or ``LINGER_S``
at most, so their datagrams travel together. The cyclic frame never waits for any of this:
the engine's real-time thread has its own frames (``crates/engine``).

Mailboxes: ``mailbox(slave)`` is the slave's one :class:`SlaveMailbox` — its mailbox counter,
repeat requests, polling of SM1's mailbox-full bit (``mailbox.py``) and its SDO client — used
by one exchange at a time (a lock per slave, never one for the bus), and the emergencies and
unsolicited messages it receives go to the slave's owner callbacks (``on_emergency``).
"""

from __future__ import annotations

import contextlib
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from typing import Any

from ether_ros.master.datagrams import (
    DATAGRAM_OVERHEAD,
    FRAME_PAYLOAD,
    DatagramService,
    Transport,
)

#: How long a round waits for the datagrams of the other parallel users before it goes out.
LINGER_S = 0.002

Request = Sequence[tuple[int, int, bytes | int]]


def _size(item: tuple[int, int, bytes | int]) -> int:
    payload = item[2]
    return DATAGRAM_OVERHEAD + (payload if isinstance(payload, int) else len(payload))


@dataclass
class _Queued:
    datagrams: list[tuple[int, int, bytes | int]]
    timeout_us: int
    retries: int
    replies: list[Any] | None = None
    error: BaseException | None = None
    done: bool = False
    posted: float = field(default_factory=time.monotonic)


@dataclass
class WorkerStats:
    """What the worker did (for tests, benchmarks and ``ether-ros master``)."""

    rounds: int = 0
    frames: int = 0
    requests: int = 0
    datagrams: int = 0


class AcyclicWorker:
    """The acyclic datagram queue of one bus over ``transport`` (the engine); a ``Transport``
    itself, so a :class:`DatagramService` runs over it (``service()``)."""

    def __init__(self, transport: Transport, timeout_us: int = 20_000, retries: int = 3) -> None:
        self.transport = transport
        self.timeout_us = timeout_us
        self.retries = retries
        self.stats = WorkerStats()
        self._queue: list[_Queued] = []
        self._cond = threading.Condition()
        self._sending = False
        # Users working in parallel now (bring-up threads): a round waits for all of them.
        self._parallel = 0
        self._mailboxes: dict[int, SlaveMailbox] = {}
        self._mailbox_guard = threading.Lock()

    # -- datagrams ------------------------------------------------------------------------------
    def service(self) -> DatagramService:
        """Named datagrams over this worker (each user may have its own: they share frames)."""
        return DatagramService(self, timeout_us=self.timeout_us, retries=self.retries)

    @contextlib.contextmanager
    def parallel(self, users: int) -> Iterator[Callable[[], None]]:
        """``users`` threads are about to work in parallel: rounds wait for all of them (or
        ``LINGER_S``). Yields ``leave``, which each user calls once it is done."""
        with self._cond:
            self._parallel += users
        left = [0]

        def leave() -> None:
            with self._cond:
                if left[0] < users:
                    left[0] += 1
                    self._parallel -= 1
                    self._cond.notify_all()

        try:
            yield leave
        finally:
            with self._cond:
                self._parallel -= users - left[0]
                left[0] = users
                self._cond.notify_all()

    def transact(self, request: Request, timeout_us: int = 20_000, retries: int = 3) -> list[Any]:
        """Queue ``request`` (datagrams that go in one frame, never split) and return its
        replies once the round that carried it is back."""
        mine = _Queued(list(request), timeout_us, retries)
        with self._cond:
            self._queue.append(mine)
            self._cond.notify_all()
            while not mine.done:
                if not self._sending and mine in self._queue and self._round_ready():
                    batch, self._queue = self._queue, []
                    self._sending = True
                    self._cond.release()
                    try:
                        self._send(batch)
                    finally:
                        self._cond.acquire()
                        self._sending = False
                        self._cond.notify_all()
                    continue
                self._cond.wait(LINGER_S / 2)
        if mine.error is not None:
            raise mine.error
        assert mine.replies is not None
        return mine.replies

    def _round_ready(self) -> bool:
        """A round goes out when every parallel user has queued, or the oldest request has
        waited ``LINGER_S`` (one sleeping between two mailbox polls), or nobody works in
        parallel (a lone user is never delayed)."""
        if len(self._queue) >= self._parallel:
            return True
        return time.monotonic() - self._queue[0].posted >= LINGER_S

    def _send(self, batch: list[_Queued]) -> None:
        """Every request of ``batch`` in as few frames as hold them (a request never split)."""
        self.stats.rounds += 1
        self.stats.requests += len(batch)
        frames: list[list[_Queued]] = []
        used = FRAME_PAYLOAD
        for r in batch:
            size = sum(_size(d) for d in r.datagrams)
            if used + size > FRAME_PAYLOAD or not frames:
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
                self.stats.frames += 1
                self.stats.datagrams += len(datagrams)
            except BaseException as exc:  # handed to every user whose datagrams were in it
                for r in group:
                    r.error, r.done = exc, True
                continue
            for r in group:
                r.replies, replies = replies[: len(r.datagrams)], replies[len(r.datagrams) :]
                r.done = True

    # -- mailboxes --------------------------------------------------------------------------
    def mailbox(self, station: int) -> SlaveMailbox:
        """The one mailbox owner of the slave at ``station`` (made on first use)."""
        with self._mailbox_guard:
            box = self._mailboxes.get(station)
            if box is None:
                box = self._mailboxes[station] = SlaveMailbox(station)
            return box

    def mailboxes(self) -> list[SlaveMailbox]:
        with self._mailbox_guard:
            return list(self._mailboxes.values())


class SlaveMailbox:
    """One slave's mailbox, owned by the worker: the ``Mailbox`` (counter, repeat requests,
    SM1 polling) and its ``SdoClient``, used by one exchange at a time. Set up again after
    every INIT (the slave's SyncManagers change); emergencies go to ``on_emergency``."""

    def __init__(self, station: int) -> None:
        self.station = station
        self.lock = threading.RLock()
        self.mailbox: Any = None
        self.sdo: Any = None
        self.on_emergency: list[Callable[[Any], None]] = []

    def attach(self, mailbox: Any, sdo: Any) -> None:
        """The slave's mailbox after its SyncManagers were (re)configured; None: it has none."""
        with self.lock:
            self.mailbox, self.sdo = mailbox, sdo
            if sdo is not None:
                handler = sdo._on_emergency

                def route(payload: bytes) -> None:
                    before = len(sdo.emergencies)
                    handler(payload)
                    if len(sdo.emergencies) > before:
                        for cb in list(self.on_emergency):
                            cb(sdo.emergencies[-1])

                mailbox.emergency_handler = route

    def client(self, name: str) -> LockedSdo | None:
        """The SDO client as its users see it: every call holds this slave's lock."""
        if self.sdo is None:
            return None
        return LockedSdo(self, name)


class LockedSdo:
    """An ``SdoClient`` whose every call holds its slave's mailbox lock, so that exchanges of
    different users (bring-up, supervisor, API, tools) never interleave on one mailbox, and
    exchanges of different slaves run side by side."""

    def __init__(self, owner: SlaveMailbox, name: str) -> None:
        self._owner = owner
        self.slave_name = name

    @property
    def client(self) -> Any:
        return self._owner.sdo

    def __getattr__(self, name: str) -> Any:
        attr = getattr(self._owner.sdo, name)
        if not callable(attr):
            return attr
        owner = self._owner

        def locked(*args: Any, **kwargs: Any) -> Any:
            with owner.lock:
                return getattr(owner.sdo, name)(*args, **kwargs)

        return locked


def run_in_parallel(
    worker: AcyclicWorker, items: Sequence[Any], work: Callable[[DatagramService, Any], None]
) -> list[BaseException | None]:
    """``work(dg, item)`` for every item, each in its own thread over the worker (their
    datagrams share frames); returns each item's error (None: done)."""
    errors: list[BaseException | None] = [None] * len(items)
    if len(items) <= 1:
        for k, item in enumerate(items):
            try:
                work(worker.service(), item)
            except BaseException as exc:
                errors[k] = exc
        return errors
    with worker.parallel(len(items)) as leave:

        def run(k: int, item: Any) -> None:
            try:
                work(worker.service(), item)
            except BaseException as exc:  # reported to the caller
                errors[k] = exc
            finally:
                leave()

        threads = [
            threading.Thread(target=run, args=(k, item), name=f"ether_ros-slave-{k}", daemon=True)
            for k, item in enumerate(items)
        ]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
    return errors
