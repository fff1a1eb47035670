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
unsolicited messages it receives go to the slave's owner callbacks (``on_emergency``,
``on_message``). An exchange reads SM1 while it waits for its reply; between exchanges the
worker polls the idle mailboxes itself (``start_polling``, every ``poll_period_s``): one round
carries the SM1 status read of every idle slave with a mailbox (they share frames), and only a
slave whose mailbox is full is read — so an emergency a slave raises while nobody talks to it
is read and routed within a period, not at the next request. A slave in an exchange (its lock
held) is skipped: the exchange reads its mailbox.
"""

from __future__ import annotations

import contextlib
import logging
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from typing import Any

from ether_ros._native.protocol import sm
from ether_ros.errors import EtherRosError
from ether_ros.master.datagrams import (
    DATAGRAM_OVERHEAD,
    FRAME_PAYLOAD,
    Cmd,
    DatagramService,
    Transport,
    fixed_address,
)
from ether_ros.master.mailbox import SM1_STATUS

log = logging.getLogger(__name__)

#: How long a round waits for the datagrams of the other parallel users before it goes out.
LINGER_S = 0.002
#: How often idle mailboxes are polled (``start_polling``): an emergency is read within this,
#: at the cost of one small datagram per slave with a mailbox per period (sharing frames).
MAILBOX_POLL_PERIOD_S = 0.02

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
    mailbox_polls: int = 0  # rounds of idle-mailbox polling
    mailbox_reads: int = 0  # idle mailboxes found full and read


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
        self._poller: threading.Thread | None = None
        self._stop_polling = threading.Event()

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
        return self.transact_each([request], timeout_us, retries)[0]

    def transact_each(
        self, requests: Sequence[Request], timeout_us: int = 20_000, retries: int = 3
    ) -> list[list[Any]]:
        """Several requests queued at once (each one frame at most; together in as few frames
        as hold them) and each one's replies; the first failure is raised."""
        queued = [_Queued(list(r), timeout_us, retries) for r in requests]
        with self._cond:
            self._queue.extend(queued)
            self._cond.notify_all()
            while not all(q.done for q in queued):
                mine = any(q in self._queue for q in queued)
                if not self._sending and mine and self._round_ready():
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
        out = []
        for q in queued:
            if q.error is not None:
                raise q.error
            assert q.replies is not None
            out.append(q.replies)
        return out

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

    # -- polling of idle mailboxes ----------------------------------------------------------
    def start_polling(self, period_s: float = MAILBOX_POLL_PERIOD_S) -> None:
        """Poll the idle mailboxes every ``period_s`` in a thread of the worker's (module doc)
        until ``stop_polling``; the cyclic frame never waits for it (the engine's own)."""
        if period_s <= 0:
            raise ValueError(f"mailbox poll period must be positive, got {period_s} s")
        if self._poller is not None:
            return
        self._stop_polling.clear()

        def run() -> None:
            while not self._stop_polling.wait(period_s):
                try:
                    self.poll_idle_mailboxes()
                except Exception:  # a bad round must not end the polling
                    log.exception("polling the idle mailboxes failed")

        self._poller = threading.Thread(target=run, name="ether_ros-mailbox-poll", daemon=True)
        self._poller.start()

    def stop_polling(self) -> None:
        poller, self._poller = self._poller, None
        if poller is None:
            return
        self._stop_polling.set()
        if poller is not threading.current_thread():
            poller.join(timeout=30)

    @property
    def polling(self) -> bool:
        return self._poller is not None

    def poll_idle_mailboxes(self) -> int:
        """One polling round: SM1's status of every idle slave with a mailbox in one round of
        requests (sharing frames), then the full ones read and their messages routed to the
        slave's owners. Returns how many mailboxes were read."""
        held: list[SlaveMailbox] = []
        for box in self.mailboxes():
            if box.lock.acquire(blocking=False):
                if box.mailbox is None:
                    box.lock.release()
                else:
                    held.append(box)
        read = 0
        try:
            if not held:
                return 0
            self.stats.mailbox_polls += 1
            reads = [(int(Cmd.FPRD), fixed_address(b.station, SM1_STATUS), 1) for b in held]
            # As many reads a request as fill a frame: few requests to queue, frames full.
            per_frame = FRAME_PAYLOAD // (DATAGRAM_OVERHEAD + 1)
            requests = [reads[k : k + per_frame] for k in range(0, len(reads), per_frame)]
            try:
                replies = self.transact_each(requests, self.timeout_us, retries=0)
            except EtherRosError as exc:
                log.debug("idle mailbox poll: %s", exc)
                return 0
            flat = [reply for request in replies for reply in request]
            for box, (data, wkc) in zip(held, flat, strict=True):
                if wkc == 1 and data and data[0] & sm.STATUS_MAILBOX_FULL:
                    read += 1
                    self.stats.mailbox_reads += 1
                    box.read_idle()
            return read
        finally:
            for box in held:
                box.lock.release()


class SlaveMailbox:
    """One slave's mailbox, owned by the worker: the ``Mailbox`` (counter, repeat requests,
    SM1 polling) and its ``SdoClient``, used by one exchange at a time. Set up again after
    every INIT (the slave's SyncManagers change). Its owners: an emergency is kept by the SDO
    client (``take_emergencies``) and handed to ``on_emergency``; a message of another type
    that nobody waits for to ``on_message`` (``(type, payload)``; counted as discarded when
    nobody takes it)."""

    def __init__(self, station: int) -> None:
        self.station = station
        self.lock = threading.RLock()
        self.mailbox: Any = None
        self.sdo: Any = None
        self.on_emergency: list[Callable[[Any], None]] = []
        self.on_message: list[Callable[[int, bytes], None]] = []

    def attach(self, mailbox: Any, sdo: Any) -> None:
        """The slave's mailbox after its SyncManagers were (re)configured; None: it has none."""
        with self.lock:
            self.mailbox, self.sdo = mailbox, sdo
            if mailbox is None:
                return
            mailbox.message_handler = self._unsolicited
            if sdo is not None:
                mailbox.emergency_handler = self._emergency

    def _emergency(self, payload: bytes) -> None:
        em = self.sdo.record_emergency(payload)
        if em is not None:
            for cb in list(self.on_emergency):
                cb(em)

    def _unsolicited(self, mbx_type: int, payload: bytes) -> bool:
        for cb in list(self.on_message):
            cb(mbx_type, payload)
        return bool(self.on_message)

    def read_idle(self) -> None:
        """Read what an idle slave put into its mailbox and route it (the caller holds the
        lock); a mailbox error reply or a failed read is logged, not raised: nobody asked."""
        with self.lock:
            if self.mailbox is None:
                return
            try:
                self.mailbox.poll_emergencies()
            except EtherRosError as exc:
                log.debug("station 0x%04X: reading its idle mailbox: %s", self.station, exc)

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
