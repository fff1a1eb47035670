"""Veth pairs, network namespaces, and running a command or one thread inside one.

:class:`VethPair` is the virtual cable between the master and the simulator: the master opens a
raw socket on one end, the simulator on the other (optionally inside its own network namespace,
so the two really are separate hosts as far as the kernel is concerned). Everything runs ``ip``
with an argument list, never through a shell, and everything created is removed again on exit.
The demo, the ROS test rig, the benchmarks and the tests build their buses with it.

A raw socket opened with an EtherType (``socket(AF_PACKET, SOCK_RAW, ETH_P_ECAT)``, as SOEM and
ethercrab open theirs) receives that EtherType from every interface of its namespace until it
is bound to one: with other EtherCAT buses on the host, the frames of those buses reach it in
that window and confuse its reply matching. A master of our tests that is not ours therefore
runs in a network namespace of its own, which holds its end of the veth pair and nothing else:
a command through ``ip netns exec`` (:func:`netns_command`), an in-process master (pysoem) by
opening its socket on a thread moved into the namespace for that moment
(:func:`thread_in_netns`). Our engine binds its socket to the interface and the EtherType
before it receives anything (``crates/link/src/packet.rs``), so it needs neither.
"""

from __future__ import annotations

import contextlib
import ctypes
import itertools
import os
import subprocess
from collections.abc import Iterator
from dataclasses import dataclass, field
from types import TracebackType

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


_counter = itertools.count()


def _ip(
    *args: str, netns: str | None = None, check: bool = True
) -> subprocess.CompletedProcess[str]:
    cmd = ["ip", *(["-n", netns] if netns else []), *args]
    result = subprocess.run(cmd, capture_output=True, text=True, check=False)
    if check and result.returncode != 0:
        raise LinkError(f"'{' '.join(cmd)}' failed: {result.stderr.strip()}")
    return result


def unique_name(prefix: str) -> str:
    """A short interface/namespace name unique to this process (interface names are ≤ 15 chars)."""
    return f"{prefix}{os.getpid() % 100000}x{next(_counter)}"[:15]


def _quiet_interface(name: str, netns: str | None) -> None:
    """Keep the kernel from sending its own packets (IPv6 router solicitations, ...) on a link
    that carries only EtherCAT, so captures and counters show only our frames."""
    path = f"/proc/sys/net/ipv6/conf/{name}/disable_ipv6"
    if netns is None and os.path.exists(path):
        with open(path, "w") as f:
            f.write("1")
    elif netns is not None:
        subprocess.run(
            ["ip", "netns", "exec", netns, "sysctl", "-qw", f"net.ipv6.conf.{name}.disable_ipv6=1"],
            capture_output=True,
            check=False,
        )


@dataclass
class VethPair:
    """A veth pair ``master`` <-> ``slave``; ``slave`` optionally lives in namespace ``netns``,
    ``master`` optionally in a namespace of its own, ``master_netns`` (for a master that is not
    ours: see ``ether_ros.netns``).

    Use as a context manager::

        with VethPair.create(netns=True) as veth:
            run_simulator(veth.slave, netns=veth.netns)
            run_master(veth.master)
    """

    master: str
    slave: str
    netns: str | None = None
    master_netns: str | None = None
    _removed: bool = field(default=False, repr=False)

    @classmethod
    def create(cls, netns: bool = False, mtu: int = 1500, master_netns: bool = False) -> VethPair:
        master, slave = unique_name("erm"), unique_name("ers")
        ns = unique_name("erns") if netns else None
        mns = unique_name("ermns") if master_netns else None
        for name in (ns, mns):
            if name:
                _ip("netns", "add", name)
        try:
            _ip("link", "add", master, "type", "veth", "peer", "name", slave)
            for end, where in ((slave, ns), (master, mns)):
                if where:
                    _ip("link", "set", end, "netns", where)
            for name, where in ((master, mns), (slave, ns)):
                _quiet_interface(name, where)
                _ip("link", "set", name, "mtu", str(mtu), "up", netns=where)
            for where in (ns, mns):
                if where:
                    _ip("link", "set", "lo", "up", netns=where)
        except Exception:
            _ip("link", "del", master, check=False, netns=mns)
            for name in (ns, mns):
                if name:
                    _ip("netns", "del", name, check=False)
            raise
        return cls(master=master, slave=slave, netns=ns, master_netns=mns)

    def set_link(self, up: bool) -> None:
        """Pull or plug the cable (both ends see carrier loss, as with a real cable)."""
        _ip("link", "set", self.master, "up" if up else "down", netns=self.master_netns)

    def remove(self) -> None:
        if self._removed:
            return
        self._removed = True
        _ip("link", "del", self.master, check=False, netns=self.master_netns)
        for name in (self.netns, self.master_netns):
            if name:
                _ip("netns", "del", name, check=False)

    def __enter__(self) -> VethPair:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.remove()


def can_create_veth() -> bool:
    """True when this process may create veth pairs (root or CAP_NET_ADMIN)."""
    try:
        pair = VethPair.create()
    except (LinkError, FileNotFoundError):
        return False
    pair.remove()
    return True
