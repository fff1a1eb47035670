"""The Fast DDS profile shipped in config/fastdds-localhost.xml keeps the node's ROS traffic on
this host (docs/security.md): a node started with it binds its UDP sockets to the loopback
address (or the discovery multicast group) only, a client with the same profile is served, and
the node reports the profile in its diagnostics. The simulator, the node and the client each in
their own process, as in production."""

from __future__ import annotations

import os
import socket
import struct
from pathlib import Path

import pytest
from test_ros_lease import Actor

from ether_ros.ros.rig import RosRig

pytestmark = [pytest.mark.netns, pytest.mark.ros]

REPO = Path(__file__).resolve().parents[2]
PROFILE = REPO / "config" / "fastdds-localhost.xml"


def udp_addresses(pid: int) -> set[str]:
    """The local addresses of every UDP socket process ``pid`` holds."""
    inodes = set()
    for fd in os.listdir(f"/proc/{pid}/fd"):
        try:
            target = os.readlink(f"/proc/{pid}/fd/{fd}")
        except OSError:
            continue
        if target.startswith("socket:["):
            inodes.add(target[8:-1])
    out = set()
    for table in ("udp", "udp6"):
        for line in Path(f"/proc/{pid}/net/{table}").read_text().splitlines()[1:]:
            fields = line.split()
            if fields[9] in inodes:
                address = fields[1].rsplit(":", 1)[0]
                if table == "udp":
                    out.add(socket.inet_ntoa(struct.pack("<I", int(address, 16))))
                else:
                    out.add(address)
    return out


def test_the_localhost_profile_keeps_the_node_on_loopback(monkeypatch: pytest.MonkeyPatch) -> None:
    if os.geteuid() != 0:
        pytest.skip("needs root (veth pairs)")
    # Fast DDS 2.x (ROS 2 Jazzy) reads this variable. The discovery range is left to the
    # profile: LOCALHOST would make rmw add a transport of its own (the node warns about it).
    # Only the rig's processes take part: a client in this process would load the profile for
    # every later test of the session (Fast DDS reads it once per process).
    monkeypatch.setenv("FASTRTPS_DEFAULT_PROFILES_FILE", str(PROFILE))
    with RosRig(REPO / "config" / "generic_io.yaml", netns=True,
                discovery_range="SYSTEM_DEFAULT") as rig:  # fmt: skip
        operator = Actor(rig, "operator")
        try:
            status = operator("lease", action="status")  # served over the profile's transports
            assert status["ok"] and "off" in status["message"], status
        finally:
            operator.close()
        assert rig.node_proc is not None
        addresses = udp_addresses(rig.node_proc.pid)
        assert addresses, "the node has no UDP socket at all"
        assert all(a == "127.0.0.1" or a.startswith("239.") for a in addresses), addresses
        log = rig.node_log.read_text()
    # What the node found, as it logged it at start (the same goes into its diagnostics).
    assert f"security: DDS profile {PROFILE}: 127.0.0.1" in log, log[-2000:]
    assert "security: control lease off" in log
    assert "security: discovery range SYSTEM_DEFAULT" in log
    assert "security: DDS security not requested (plugins absent)" in log
