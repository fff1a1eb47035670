"""A complete ROS rig on one machine: a veth pair, the simulator on one end (its own process),
the ``ether_ros`` node on the other (its own process, ``ether-ros run``) and a ROS 2 client in
this process — with a ROS domain of its own so parallel rigs never hear each other.

Used by the demo, the acceptance tests and the benchmarks::

    with RosRig("config/laelaps.yaml") as rig:
        rig.client.write("all", "y_cntr_traj1000", 599)
        rig.client.write("all", "b_ellipse100", 4)
        rig.sim("probe", slave=0)

Everything is started with argument lists (never a shell) and stopped again on exit: the node
with SIGINT (so it deactivates cleanly), the simulator with SIGTERM, the veth pair removed.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from types import TracebackType
from typing import Any

import rclpy
from rclpy.context import Context

from ether_ros.errors import EtherRosError
from ether_ros.netns import VethPair
from ether_ros.ros.client import EtherRosClient


class RigError(EtherRosError):
    """A rig process did not start (the message carries the end of its log)."""


#: ``K/N``: this process is the Kth of N running rigs side by side (a parallel test run sets it
#: per worker), and takes its domains from the Kth of N equal slices of 1..200 only, so that two
#: such processes never share a domain whatever their pids.
DOMAIN_SLICE_ENV = "ETHER_ROS_DOMAIN_SLICE"


def _domain_slice() -> tuple[int, int]:
    text = os.environ.get(DOMAIN_SLICE_ENV, "")
    try:
        k, n = (int(part) for part in text.split("/"))
    except ValueError:
        return 0, 1
    return (k, n) if 0 <= k < n <= 200 else (0, 1)


def domain_for(pid: int, offset: int = 0) -> int:
    """A ROS domain id for this process: 1..200, distinct for distinct pids (mostly), and
    within this process's slice (``ETHER_ROS_DOMAIN_SLICE``) when it has one."""
    k, n = _domain_slice()
    width = 200 // n
    return 1 + k * width + (pid * 7 + offset) % width


class RosRig:
    def __init__(
        self,
        config: str | Path,
        *,
        inactive: bool = False,
        domain_id: int | None = None,
        netns: bool = False,
        node_name: str = "ether_comm",
        raw: bool = False,
        log_dir: str | Path | None = None,
        client_options: dict[str, Any] | None = None,
        node_args: list[str] | None = None,
        discovery_range: str = "LOCALHOST",
    ) -> None:
        self.config = str(Path(config).resolve())
        self.inactive = inactive
        self.domain_id = domain_id if domain_id is not None else domain_for(os.getpid())
        self.netns = netns
        self.node_name = node_name
        self.raw = raw
        self.client_options = dict(client_options or {})
        self.node_args = list(node_args or [])  # more `ether-ros run` options
        # ROS_AUTOMATIC_DISCOVERY_RANGE of the rig's processes (SYSTEM_DEFAULT: as the DDS
        # profile in the environment says, docs/security.md).
        self.discovery_range = discovery_range
        self._tmp = tempfile.TemporaryDirectory(prefix="ether_ros_rig_")
        self.dir = Path(log_dir) if log_dir is not None else Path(self._tmp.name)
        self.veth: VethPair | None = None
        self.sim_proc: subprocess.Popen[bytes] | None = None
        self.node_proc: subprocess.Popen[bytes] | None = None
        self.context: Context | None = None
        self._client: EtherRosClient | None = None

    # ------------------------------------------------------------------------ processes
    @property
    def env(self) -> dict[str, str]:
        env = dict(os.environ)
        env["ROS_DOMAIN_ID"] = str(self.domain_id)
        env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = self.discovery_range
        env["PYTHONUNBUFFERED"] = "1"
        return env

    @property
    def control_socket(self) -> Path:
        return self.dir / "sim.sock"

    @property
    def sim_log(self) -> Path:
        return self.dir / "sim.log"

    @property
    def node_log(self) -> Path:
        return self.dir / "node.log"

    def start_sim(self) -> None:
        assert self.veth is not None
        cmd = [
            sys.executable,
            "-m",
            "ether_ros.cli.main",
            "sim",
            self.config,
            "--interface",
            self.veth.slave,
            "--control",
            str(self.control_socket),
        ]
        if self.veth.netns:
            cmd = ["ip", "netns", "exec", self.veth.netns, *cmd]
        with open(self.sim_log, "wb") as log:
            self.sim_proc = subprocess.Popen(
                cmd, stdout=log, stderr=subprocess.STDOUT, env=self.env
            )
        self._wait_for_line(self.sim_proc, self.sim_log, "ready", "simulator", 30.0)

    def start_node(self, inactive: bool | None = None) -> None:
        assert self.veth is not None
        cmd = [
            sys.executable,
            "-m",
            "ether_ros.cli.main",
            "run",
            self.config,
            "--interface",
            self.veth.master,
        ]
        if self.inactive if inactive is None else inactive:
            cmd.append("--inactive")
        cmd += self.node_args
        with open(self.node_log, "ab") as log:
            self.node_proc = subprocess.Popen(
                cmd, stdout=log, stderr=subprocess.STDOUT, env=self.env
            )
        # Generous: a node brings its bus up before it says it runs, which took over 60 s with
        # the host at load 19 (a node that fails says so at once and is reported then).
        self._wait_for_line(self.node_proc, self.node_log, "ether-ros run:", "node", 180.0)

    def stop_node(self, timeout: float = 15.0) -> int | None:
        """SIGINT (the node deactivates: safe outputs, SAFEOP), then SIGKILL if it hangs."""
        proc, self.node_proc = self.node_proc, None
        if proc is None:
            return None
        if proc.poll() is None:
            proc.send_signal(signal.SIGINT)
            try:
                proc.wait(timeout)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
        return proc.returncode

    @staticmethod
    def _wait_for_line(
        proc: subprocess.Popen[bytes], log: Path, marker: str, what: str, timeout: float
    ) -> None:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            text = log.read_text(errors="replace") if log.exists() else ""
            if marker in text:
                if "error:" in text.split(marker, 1)[1].splitlines()[0]:
                    raise RigError(f"{what} failed:\n{text[-2000:]}")
                return
            if proc.poll() is not None:
                raise RigError(f"{what} exited with {proc.returncode}:\n{text[-2000:]}")
            time.sleep(0.05)
        raise RigError(f"{what} not ready within {timeout:g} s:\n{log.read_text()[-2000:]}")

    # ------------------------------------------------------------------------ ROS client
    @property
    def client(self) -> EtherRosClient:
        if self._client is None:
            self.context = Context()
            rclpy.init(context=self.context, domain_id=self.domain_id)
            self._client = EtherRosClient(
                self.node_name, context=self.context, raw=self.raw, **self.client_options
            )
        return self._client

    def sim(self, op: str, **args: Any) -> Any:
        """One request to the simulator's control socket (probe, slave_info, stats, fault)."""
        from ether_ros.sim.control import request

        return request(self.control_socket, {"op": op, **args})

    # ------------------------------------------------------------------------ lifetime
    def __enter__(self) -> RosRig:
        try:
            self.veth = VethPair.create(netns=self.netns)
            self.start_sim()
            self.start_node()
        except BaseException:
            self.close()
            raise
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()

    def close(self) -> None:
        if self._client is not None:
            self._client.close()
            self._client = None
        if self.context is not None:
            self.context.try_shutdown()
            self.context = None
        self.stop_node()
        if self.sim_proc is not None:
            if self.sim_proc.poll() is None:
                self.sim_proc.terminate()
                try:
                    self.sim_proc.wait(10)
                except subprocess.TimeoutExpired:
                    self.sim_proc.kill()
                    self.sim_proc.wait()
            self.sim_proc = None
        if self.veth is not None:
            self.veth.remove()
            self.veth = None
        self._tmp.cleanup()
