"""Shared fixtures. Tests that need veth pairs create and remove them themselves."""

from __future__ import annotations

import os
from collections.abc import Iterator
from pathlib import Path

import pytest

from ether_ros.sim.proof import SimProcess
from ether_ros.testing.netns import VethPair, can_create_veth

REPO = Path(__file__).resolve().parent.parent

# `make test` runs the tests in parallel (pytest-xdist, one worker per core): each worker takes
# its ROS domains from a slice of its own (ros/rig.py, domain_for), so two workers' nodes never
# meet; interface and namespace names are unique per process already (netns.unique_name).
_WORKER = os.environ.get("PYTEST_XDIST_WORKER", "")
if _WORKER.startswith("gw"):
    os.environ["ETHER_ROS_DOMAIN_SLICE"] = (
        f"{int(_WORKER[2:])}/{os.environ.get('PYTEST_XDIST_WORKER_COUNT', '1')}"
    )
# The parsed ESI files are cached on disk (config/esi_cache.py): the tests share one cache
# beside their virtual environment, never the user's own.
os.environ.setdefault("ETHER_ROS_CACHE_DIR", str(REPO / ".venv" / "ether_ros-cache"))
LAELAPS = REPO / "config" / "laelaps.yaml"


# Fixtures that create veth pairs or network namespaces: a test that uses one (directly or
# through another fixture) needs root, and carries the `netns` marker whether or not its module
# says so (`pytest -m "not netns"` runs what an unprivileged user can).
ROOT_FIXTURES = frozenset({"veth", "veth_ns", "veth_apart", "sim_iface"})


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    for item in items:
        if ROOT_FIXTURES & set(getattr(item, "fixturenames", ())):
            item.add_marker(pytest.mark.netns)


@pytest.fixture(scope="session")
def repo() -> Path:
    return REPO


@pytest.fixture(scope="session")
def veth_allowed() -> bool:
    return can_create_veth()


@pytest.fixture
def veth(veth_allowed: bool) -> Iterator[VethPair]:
    """A fresh veth pair (master end in this namespace, slave end too)."""
    if not veth_allowed:
        pytest.fail("creating a veth pair needs root or CAP_NET_ADMIN; run the tests as root")
    with VethPair.create() as pair:
        yield pair


@pytest.fixture
def veth_ns(veth_allowed: bool) -> Iterator[VethPair]:
    """A fresh veth pair whose slave end lives in its own network namespace."""
    if not veth_allowed:
        pytest.fail("creating a network namespace needs root; run the tests as root")
    with VethPair.create(netns=True) as pair:
        yield pair


@pytest.fixture
def veth_apart(veth_allowed: bool) -> Iterator[VethPair]:
    """A fresh veth pair with each end in a network namespace of its own: for a master that is
    not ours (pysoem, ethercrab), whose raw socket would otherwise see the EtherCAT frames of
    every other bus on the host before it is bound (``ether_ros.netns``)."""
    if not veth_allowed:
        pytest.fail("creating a network namespace needs root; run the tests as root")
    with VethPair.create(netns=True, master_netns=True) as pair:
        yield pair


@pytest.fixture(scope="module")
def sim_iface(veth_allowed: bool) -> Iterator[str]:
    """The master-side interface of the simulated Laelaps bus (config/laelaps.yaml), run in its
    own process and network namespace; one simulator serves every test of a module."""
    if not veth_allowed:
        pytest.fail("creating a network namespace needs root; run the tests as root")
    with VethPair.create(netns=True) as veth, SimProcess(LAELAPS, veth.slave, veth.netns):
        yield veth.master
