"""Running a command, or one thread, inside a network namespace.

A raw socket opened with an EtherType (``socket(AF_PACKET, SOCK_RAW, ETH_P_ECAT)``, as SOEM and
ethercrab open theirs) receives that EtherType from every interface of its namespace until it
is bound to one: with other EtherCAT buses on the host, the frames of those buses reach it in
that window and confuse its reply matching. A master of our tests that is not ours therefore
runs in a network namespace of its own, which holds its end of the veth pair and nothing else:
a command through ``ip netns exec`` (:func:`netns_command`), an in-process master (pysoem) by
opening its socket on a thread moved into the namespace for that moment
(:func:`thread_in_netns`). Our engine binds its socket to the interface and the EtherType
before it receives anything (``crates/engine/src/link.rs``), so it needs neither.
"""

from __future__ import annotations

import contextlib
import ctypes
import os
from collections.abc import Iterator

from ether_ros.errors import LinkError

#: setns(2)'s namespace type for network namespaces.
CLONE_NEWNET = 0x40000000
#: Where ``ip netns add NAME`` keeps its namespaces.
NETNS_DIR = "/run/netns"


def netns_command(netns: str | None, argv: list[str]) -> list[str]:
    """Prefix ``argv`` so that it runs inside ``netns`` (or unchanged when None)."""
    return ["ip", "netns", "exec", netns, *argv] if netns else list(argv)


@contextlib.contextmanager
def thread_in_netns(netns: str | None) -> Iterator[None]:
    """The calling thread inside network namespace ``netns`` for the ``with`` block, then back
    in its own (a network namespace is a property of the thread, not of the process: the other
    threads never leave theirs). A socket opened in the block stays in ``netns`` for its life,
    whichever thread uses it later. None: no change."""
    if netns is None:
        yield
        return
    libc = ctypes.CDLL(None, use_errno=True)
    own = os.open("/proc/thread-self/ns/net", os.O_RDONLY | os.O_CLOEXEC)
    try:
        try:
            target = os.open(os.path.join(NETNS_DIR, netns), os.O_RDONLY | os.O_CLOEXEC)
        except OSError as exc:
            raise LinkError(f"no network namespace {netns!r}: {exc.strerror}") from None
        try:
            if libc.setns(target, CLONE_NEWNET) != 0:
                err = ctypes.get_errno()
                raise LinkError(f"cannot enter network namespace {netns!r}: {os.strerror(err)}")
        finally:
            os.close(target)
        try:
            yield
        finally:
            if libc.setns(own, CLONE_NEWNET) != 0:  # pragma: no cover - the kernel refused?
                err = ctypes.get_errno()
                raise LinkError(f"cannot return to this thread's namespace: {os.strerror(err)}")
    finally:
        os.close(own)
