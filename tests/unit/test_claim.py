"""The interface claim (ether_ros/claim.py): one owner per interface and role, gone with its
process, serving checked requests to its own user only. No interface is needed: the claim is
an abstract socket named after one."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import uuid

import pytest

from ether_ros.claim import (
    InterfaceBusy,
    InterfaceClaim,
    OwnerClient,
    OwnerError,
    ask,
    socket_name,
)
from ether_ros.errors import BusError
from ether_ros.testing.wait import wait_for


def _interface() -> str:
    return f"test{uuid.uuid4().hex[:10]}"


def test_a_second_claim_is_refused_naming_the_owner_and_free_after_release() -> None:
    iface = _interface()
    first = InterfaceClaim.take(iface, "master", node="/ether_comm")
    try:
        with pytest.raises(InterfaceBusy) as refused:
            InterfaceClaim.take(iface, "master")
        assert refused.value.owner["pid"] == os.getpid()
        assert refused.value.owner["node"] == "/ether_comm"
        text = str(refused.value)
        assert f"another master is already running on {iface} (pid {os.getpid()}" in text
        assert "node /ether_comm" in text
        # Another role on the same interface is another claim (the simulator's far end).
        with InterfaceClaim.take(iface, "sim"):
            pass
    finally:
        first.release()
    InterfaceClaim.take(iface, "master").release()


def test_a_claim_ends_with_its_process_however_it_ends() -> None:
    iface = _interface()
    holder = subprocess.Popen(
        [
            sys.executable,
            "-c",
            "import sys, time; from ether_ros.claim import InterfaceClaim;"
            f"InterfaceClaim.take({iface!r}); print('held', flush=True); time.sleep(600)",
        ],
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert holder.stdout is not None and holder.stdout.readline().strip() == "held"
        with pytest.raises(InterfaceBusy) as refused:
            InterfaceClaim.take(iface)
        assert refused.value.owner["pid"] == holder.pid
    finally:
        holder.send_signal(signal.SIGKILL)
        holder.wait()
    # No file, no stale lock: free the moment the process is gone.
    InterfaceClaim.take(iface).release()


def test_requests_are_checked_and_errors_carry_their_type_and_code() -> None:
    iface = _interface()

    def fails(_request: object) -> None:
        raise BusError("slave 3 (leg): no answer")

    with InterfaceClaim.take(iface) as claim:
        claim.serve("echo", lambda r: r.get("value"))
        claim.serve("fails", fails)
        with OwnerClient(iface) as client:
            assert client.request("echo", value=[1, 2]) == [1, 2]
            with pytest.raises(OwnerError, match=r"unknown request 'nope' \(this master: "):
                client.request("nope")
            with pytest.raises(OwnerError) as err:
                client.request("fails")
            assert err.value.kind == "BusError" and "no answer" in str(err.value)
            # Not JSON, or no op: an error answer, and the connection goes on.
            client._sock.sendall(b"not json\n")
            assert b"one JSON object per line" in client._reader.readline()
            client._sock.sendall(b'{"value": 1}\n')
            assert b'needs \\"op\\"' in client._reader.readline()
            assert client.request("who")["pid"] == os.getpid()
    # Released: nobody answers.
    assert OwnerClient.find(iface) is None
    with pytest.raises(ConnectionError):
        ask(iface, "who")


@pytest.mark.skipif(os.geteuid() != 0, reason="dropping to another user needs root")
@pytest.mark.netns  # switches user: needs root
def test_only_the_owner_s_user_or_root_is_served() -> None:
    iface = _interface()
    with InterfaceClaim.take(iface):
        child = subprocess.run(
            [
                sys.executable,
                "-c",
                "import os, socket; os.setgid(65534); os.setuid(65534);"
                "s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM);"
                f"s.connect({socket_name('master', iface)!r});"
                's.sendall(b\'{"op": "who"}\\n\');'
                "print(s.makefile('rb').readline().decode())",
            ],
            capture_output=True,
            text=True,
            timeout=60,
            check=False,
        )
    assert child.returncode == 0, child.stderr
    assert "PermissionError" in child.stdout and "pid" not in child.stdout


def test_a_client_finds_the_owner_only_while_it_holds_the_claim() -> None:
    iface = _interface()
    claim = InterfaceClaim.take(iface, "master", node="/n")
    client = OwnerClient.find(iface)
    assert client is not None and client.owner["node"] == "/n"
    client.close()
    claim.release()
    wait_for("the claim to be gone", lambda: OwnerClient.find(iface) is None, timeout=5)
