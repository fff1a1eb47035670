"""Least privilege (docs/capabilities.md): the master runs as an unprivileged user holding only
CAP_NET_RAW, CAP_SYS_NICE and CAP_IPC_LOCK, and refuses with a one-line error naming the
capability that is missing. Nothing in the repository or the virtual environment is setuid.

The commands run as ``nobody`` through util-linux ``setpriv``: the three capabilities are the
only ones in the bounding, inheritable, permitted, effective and ambient sets, and the resource
limits that could stand in for them (RLIMIT_RTPRIO, RLIMIT_MEMLOCK) are set to nothing, so the
capabilities alone carry the privilege. The simulator runs as root in its own namespace.
"""

from __future__ import annotations

import os
import resource
import shutil
import stat
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from ether_ros.sim.proof import SimProcess
from ether_ros.testing.netns import VethPair

pytestmark = pytest.mark.netns

REPO = Path(__file__).resolve().parents[2]
LAELAPS = REPO / "config" / "laelaps.yaml"
CAPABILITIES = ("net_raw", "sys_nice", "ipc_lock")
# Capability bit numbers (linux/capability.h).
CAP_BITS = {"net_raw": 13, "ipc_lock": 14, "sys_nice": 23}
# The xdp link also loads and attaches an XDP program (docs/capabilities.md).
XDP_CAPABILITIES = (*CAPABILITIES, "net_admin", "bpf")
NOBODY_UID = 65534


def setpriv_argv(caps: tuple[str, ...]) -> list[str]:
    """Run as nobody with exactly ``caps`` (in every capability set)."""
    setpriv = shutil.which("setpriv")
    if setpriv is None:
        pytest.fail("setpriv (util-linux) is missing: scripts/bootstrap.sh installs util-linux")
    wanted = ",".join(["-all", *(f"+{c}" for c in caps)])
    return [
        setpriv, "--reuid=nobody", "--regid=nogroup", "--clear-groups",
        f"--bounding-set={wanted}", f"--inh-caps={wanted}", f"--ambient-caps={wanted}",
    ]  # fmt: skip


def no_rlimit_privileges() -> None:
    """In the child before exec: no real-time priority and only 64 KiB of lockable memory
    without the capabilities."""
    resource.setrlimit(resource.RLIMIT_RTPRIO, (0, 0))
    resource.setrlimit(resource.RLIMIT_MEMLOCK, (65536, 65536))


def run_as_nobody(
    caps: tuple[str, ...], *argv: str, timeout: float = 60
) -> subprocess.CompletedProcess[str]:
    env = {
        "PATH": os.environ.get("PATH", "/usr/bin:/bin"),
        "HOME": "/nonexistent",
        "PYTHONDONTWRITEBYTECODE": "1",  # the checkout is not writable for nobody
        "LANG": "C.UTF-8",
    }
    return subprocess.run(
        [*setpriv_argv(caps), sys.executable, *argv],
        capture_output=True,
        text=True,
        timeout=timeout,
        env=env,
        preexec_fn=no_rlimit_privileges,
        check=False,
    )


def ether_ros_as_nobody(caps: tuple[str, ...], *args: str) -> subprocess.CompletedProcess[str]:
    return run_as_nobody(caps, "-m", "ether_ros.cli.main", *args)


def path_components(path: Path) -> list[Path]:
    return [path, *path.parents]


@pytest.fixture(scope="module")
def nobody_can_run_the_venv() -> Iterator[None]:
    """Let nobody reach the interpreter: the venv's python may live under a directory closed to
    others (pyenv under /root). Adds only search permission (o+x) to the directories on the way
    that lack it, and restores their modes afterwards."""
    if os.geteuid() != 0:
        pytest.fail("switching to nobody needs root; run the acceptance tests as root")
    targets = [Path(sys.executable).resolve(), Path(sys.prefix), Path(sys.base_prefix), REPO]
    changed: dict[Path, int] = {}
    for target in targets:
        for d in path_components(target)[1:]:
            mode = d.stat().st_mode
            if d not in changed and not mode & stat.S_IXOTH:
                changed[d] = stat.S_IMODE(mode)
                d.chmod(stat.S_IMODE(mode) | stat.S_IXOTH)
    try:
        probe = run_as_nobody(CAPABILITIES, "-c", "import ether_ros._native")
        if probe.returncode != 0:
            pytest.skip(
                "environment: user nobody cannot import ether_ros from this checkout "
                f"even with o+x on the path ({probe.stderr.strip().splitlines()[-1:]})"
            )
        yield
    finally:
        for d, mode in changed.items():
            d.chmod(mode)


@pytest.fixture
def sim(veth_ns: VethPair) -> Iterator[SimProcess]:
    with SimProcess(LAELAPS, veth_ns.slave, veth_ns.netns) as s:
        yield s


def assert_one_line_error(r: subprocess.CompletedProcess[str], naming: str) -> None:
    assert r.returncode != 0, r.stdout
    assert "Traceback" not in r.stderr, r.stderr
    assert r.stderr.count("\n") == 1 and r.stderr.endswith("\n"), repr(r.stderr)
    assert naming in r.stderr, r.stderr


def test_the_three_capabilities_and_nothing_else_are_enough(
    nobody_can_run_the_venv: None, sim: SimProcess, veth_ns: VethPair
) -> None:
    # The child really is nobody with exactly the three capabilities.
    r = run_as_nobody(
        CAPABILITIES,
        "-c",
        "import os; s = dict(l.split(':\\t') for l in open('/proc/self/status').read()"
        ".splitlines() if ':\\t' in l); print(os.getuid(), s['CapEff'], s['CapBnd'])",
    )
    assert r.returncode == 0, r.stderr
    caps = sum(1 << CAP_BITS[c] for c in CAPABILITIES)
    assert r.stdout.split() == [str(NOBODY_UID), f"{caps:016x}", f"{caps:016x}"]

    r = ether_ros_as_nobody(CAPABILITIES, "slaves", "--interface", veth_ns.master)
    assert r.returncode == 0, r.stderr
    assert len(r.stdout.strip().splitlines()) == 4

    # laelaps.yaml asks for SCHED_FIFO 80 on CPU 1 with locked memory.
    r = ether_ros_as_nobody(
        CAPABILITIES, "bench", "cycle", str(LAELAPS), "--interface", veth_ns.master,
        "--cycle-us", "1000", "--seconds", "2", "--drift-frames", "300",
    )  # fmt: skip
    assert r.returncode == 0, r.stderr
    assert "cycles" in r.stdout and "round trip" in r.stdout


def test_without_cap_net_raw_the_error_names_it(
    nobody_can_run_the_venv: None, veth: VethPair
) -> None:
    # Fails at the raw socket, before any frame: no simulator needed.
    caps = ("sys_nice", "ipc_lock")
    r = ether_ros_as_nobody(caps, "slaves", "--interface", veth.master)
    assert_one_line_error(r, "CAP_NET_RAW")
    r = ether_ros_as_nobody(
        caps, "bench", "cycle", str(LAELAPS), "--interface", veth.master, "--seconds", "1"
    )
    assert_one_line_error(r, "CAP_NET_RAW")


@pytest.mark.parametrize(
    ("missing", "named"), [("sys_nice", "CAP_SYS_NICE"), ("ipc_lock", "CAP_IPC_LOCK")]
)
def test_without_the_realtime_capabilities_the_error_names_them(
    nobody_can_run_the_venv: None, sim: SimProcess, veth_ns: VethPair, missing: str, named: str
) -> None:
    caps = tuple(c for c in CAPABILITIES if c != missing)
    r = ether_ros_as_nobody(
        caps, "bench", "cycle", str(LAELAPS), "--interface", veth_ns.master,
        "--cycle-us", "1000", "--seconds", "1", "--drift-frames", "300",
    )  # fmt: skip
    assert_one_line_error(r, named)


def test_the_xdp_link_needs_net_admin_and_bpf_and_names_what_is_missing(
    nobody_can_run_the_venv: None, sim: SimProcess, veth_ns: VethPair
) -> None:
    def slaves(caps: tuple[str, ...]) -> subprocess.CompletedProcess[str]:
        return ether_ros_as_nobody(caps, "slaves", "--interface", veth_ns.master, "--link", "xdp")

    r = slaves(XDP_CAPABILITIES)
    assert r.returncode == 0, r.stderr
    assert len(r.stdout.strip().splitlines()) == 4
    assert_one_line_error(slaves(CAPABILITIES), "missing CAP_NET_ADMIN and CAP_BPF")
    without_bpf = tuple(c for c in XDP_CAPABILITIES if c != "bpf")
    assert_one_line_error(slaves(without_bpf), "missing CAP_BPF")
    without_admin = tuple(c for c in XDP_CAPABILITIES if c != "net_admin")
    assert_one_line_error(slaves(without_admin), "missing CAP_NET_ADMIN")
    without_raw = tuple(c for c in XDP_CAPABILITIES if c != "net_raw")
    assert_one_line_error(slaves(without_raw), "CAP_NET_RAW")


def setid_files(root: Path) -> list[Path]:
    """Regular files under ``root`` with the setuid or setgid bit (symlinks not followed)."""
    found = []
    for dirpath, _dirs, files in os.walk(root):
        for name in files:
            p = Path(dirpath, name)
            try:
                mode = p.lstat().st_mode
            except OSError:
                continue  # removed meanwhile (other tests build in the tree)
            if stat.S_ISREG(mode) and mode & (stat.S_ISUID | stat.S_ISGID):
                found.append(p)
    return found


def test_the_finder_sees_a_setuid_file(tmp_path: Path) -> None:
    f = tmp_path / "wrapper"
    f.write_text("#!/bin/sh\n")
    f.chmod(0o4755)
    assert setid_files(tmp_path) == [f]


def test_nothing_is_setuid() -> None:
    roots = [REPO, Path(sys.prefix)]  # the checkout and the installed package's venv
    found = [p for root in roots for p in setid_files(root)]
    interpreter = Path(sys.executable).resolve()
    if interpreter.stat().st_mode & (stat.S_ISUID | stat.S_ISGID):
        found.append(interpreter)
    assert found == []
