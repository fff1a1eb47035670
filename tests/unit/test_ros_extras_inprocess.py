"""A drive's extras (``extras:`` of an axis, docs/cia402.md) over ROS, with the node and the
simulator's CiA 402 drive model in one process (config/arm6.yaml, the elbow with extras):
``joint_extras`` carries the drive's values in SI, ``set_extras`` commands the writable ones
and refuses, writing nothing, what ``Axis.set_extras`` refuses; top's standalone source shows
them under the axis."""

from __future__ import annotations

import math
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from test_ros_node_inprocess import running_node

from ether_ros.ros.client import EtherRosClient

# netns: the bus runs with its configuration's realtime section (SCHED_FIFO, locked memory).
pytestmark = [pytest.mark.ros, pytest.mark.netns]

REPO = Path(__file__).resolve().parents[2]
EXTRAS = ["inputs", "outputs", "velocity_offset"]


@pytest.fixture(scope="module")
def arm() -> Iterator[tuple[Any, EtherRosClient]]:
    # The shipped arm6: its elbow maps the drive's inputs, outputs and velocity offset.
    with running_node(13, REPO / "config" / "arm6.yaml") as (node, client, _net):
        ok, message = node.run_command("start")
        assert ok, message
        yield node, client


def extras(client: EtherRosClient, condition: Any = None) -> dict[str, float]:
    """The elbow's extras from the next joint_extras that satisfies ``condition``."""

    def latest(lt: Any) -> dict[str, float] | None:
        msg = lt.joint_extras
        if msg is None:
            return None
        assert len(msg.joints) == len(msg.names) == len(msg.values)
        assert set(msg.joints) == {"elbow"}  # only axes with extras have entries
        values = dict(zip(msg.names, msg.values, strict=True))
        return values if condition is None or condition(values) else None

    result: dict[str, float] = client.wait_for(latest, timeout=20.0)
    return result


def test_joint_extras_carries_the_drives_values_in_si(arm: Any) -> None:
    node, client = arm
    first = extras(client)
    assert list(first) == EXTRAS  # configuration order
    # The drive model wires digital outputs 16-31 back to inputs 16-31: commanded over ROS,
    # the outputs come back on the topic as inputs.
    ok, message = client.set_extras("elbow", {"outputs": float(0x0005_0000)})
    assert ok, message
    looped = extras(client, lambda v: int(v["inputs"]) & 0xFFFF_0000 == 0x0005_0000)
    assert looped["outputs"] == float(0x0005_0000)
    # SI: the velocity offset in rad/s (the object holds counts/s, velocity_scale apart).
    ok, message = client.set_extras("elbow", {"velocity_offset": 0.1})
    assert ok, message
    scaled = extras(client, lambda v: v["velocity_offset"] != 0.0)
    assert scaled["velocity_offset"] == pytest.approx(0.1, abs=1e-5)
    raw = node._axes["elbow"].bus.read("elbow_drive", node._axes["elbow"].spec.extras[
        "velocity_offset"].variable.key)  # fmt: skip
    assert raw == round(0.1 / 7.66990394e-6)
    assert node._axes["elbow"].extras == pytest.approx(scaled, abs=1e-5)
    ok, message = client.set_extras("elbow", {"velocity_offset": 0.0})
    assert ok, message


@pytest.mark.parametrize(
    ("joint", "values", "why"),
    [
        ("elbow", {"inputs": 1.0}, "is an input"),
        ("elbow", {"outputs": 1.0, "nope": 1.0}, "no extra 'nope' (extras: inputs, outputs"),
        ("elbow", {"outputs": math.nan}, "not a finite number"),
        ("elbow", {"outputs": math.inf}, "not a finite number"),
        ("elbow", {"outputs": 2.0**33}, "extra 'outputs'"),
        ("wrist_1", {"outputs": 1.0}, "no extra 'outputs' (extras: none)"),
        ("nope", {"outputs": 1.0}, "unknown joint(s) 'nope'"),
        ("", {"outputs": 1.0}, "needs the joint"),
    ],
)
def test_bad_set_extras_is_refused_and_writes_nothing(
    arm: Any, joint: str, values: dict[str, float], why: str
) -> None:
    node, client = arm
    elbow = node._axes["elbow"]
    before = elbow.extras["outputs"]
    ok, message = client.set_extras(joint, values)
    assert not ok and why in message, message
    assert elbow.extras["outputs"] == before


def test_set_extras_without_the_lease_or_with_unpaired_arrays_is_refused(arm: Any) -> None:
    """The control lease is checked first (arm6 has it on; the client holds it), then the
    service's parallel arrays, before anything is looked up; nothing is written."""
    from ether_ros_msgs.srv import SetExtras

    node, client = arm
    elbow = node._axes["elbow"]
    before = elbow.extras["outputs"]
    token = client._token()  # acquires the lease if this test runs alone
    req = SetExtras.Request(joint="elbow", names=["outputs"], values=[before + 1.0])
    resp = client._call(client._set_extras, req, 10.0)  # no token
    assert not resp.success and "set_extras refused: the control lease is held by" in resp.message
    req = SetExtras.Request(
        joint="elbow", names=["outputs", "velocity_offset"], values=[1.0], lease=token
    )
    resp = client._call(client._set_extras, req, 10.0)
    assert not resp.success and "2 extra name(s) but 1 value(s)" in resp.message
    req = SetExtras.Request(
        joint="elbow", names=["outputs", "outputs"], values=[1.0, 2.0], lease=token
    )
    resp = client._call(client._set_extras, req, 10.0)
    assert not resp.success and "named twice" in resp.message
    assert elbow.extras["outputs"] == before


def test_top_shows_the_extras_under_their_axis(arm: Any) -> None:
    """top's standalone source (BusLiveSource) on the same bus: the elbow's extras on the line
    under it, the other axes without such a line."""
    from ether_ros.tools.live import BusLiveSource, axes_text

    node, client = arm
    ok, message = client.set_extras("elbow", {"outputs": float(0x0003_0000)})
    assert ok, message
    extras(client, lambda v: v["outputs"] == float(0x0003_0000))
    source = BusLiveSource(node._bus, owns_bus=False)
    snap = source.poll()
    rows = {a.joint: a.extras for a in snap.axes}
    assert rows["elbow"]["outputs"] == float(0x0003_0000)
    assert all(not v for j, v in rows.items() if j != "elbow")
    lines = axes_text(snap).splitlines()
    elbow = next(i for i, line in enumerate(lines) if line.split()[0] == "elbow")
    assert "outputs=196608" in lines[elbow + 1].split()
    assert len(lines) == 1 + len(rows) + 1  # header, one line per axis, the elbow's extras
