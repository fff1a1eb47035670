"""Drive the simulator with an independent master (pysoem, i.e. SOEM): the proof that the
virtual bus behaves like the hardware, used by the acceptance tests and ``ether-ros demo``.

- :class:`SimProcess` runs ``ether-ros sim CONFIG --interface IFACE`` as a separate process
  (optionally inside a network namespace) and talks to its control socket.
- :class:`SoemBus` brings the bus up with pysoem the way a SOEM application does
  (``config_init`` → ``config_dc`` → SYNC0 in the PREOP→SAFEOP hook → ``config_map`` → OP) and
  runs process-data cycles.
- :func:`table_6_1` gives the trot parameters of the thesis per leg.
"""

from __future__ import annotations

import math
import os
import selectors
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from types import TracebackType
from typing import Any

from ether_ros._native.protocol import coe
from ether_ros.config.bus import BusConfig, SlaveConfig
from ether_ros.config.process import ProcessLayout
from ether_ros.errors import BusError, EtherRosError
from ether_ros.laelaps import TROT_A_CM, TROT_B_CM, leg_outputs
from ether_ros.netns import netns_command, thread_in_netns
from ether_ros.sim.control import request, socket_path
from ether_ros.sim.spec import bus_order

INIT, PREOP, SAFEOP, OP = 1, 2, 4, 8


class SimProcess:
    """``ether-ros sim`` in its own process; a context manager that stops it on exit."""

    def __init__(
        self,
        config: Path | None,
        interface: str,
        netns: str | None = None,
        extra: Sequence[str] = (),
        link: str = "packet",
        ready_timeout: float = 30.0,
    ) -> None:
        """``config`` is the bus YAML; None with ``extra`` such as ``["--esi", FILE]``;
        ``link`` is how the simulator meets the wire (``ether-ros sim --link``);
        ``ready_timeout`` how long the context manager waits for it to start (loading big
        vendor ESI files on a loaded machine takes a while)."""
        self.config = None if config is None else Path(config)
        self.ready_timeout = ready_timeout
        self.extra = (*extra, "--link", link)
        self.interface = interface
        self.netns = netns
        self.control = socket_path(interface)
        self.proc: subprocess.Popen[str] | None = None
        self.ready_line = ""
        self.returncode: int | None = None

    def start(self, timeout: float = 30.0) -> SimProcess:
        config = [] if self.config is None else [str(self.config)]
        argv = [sys.executable, "-m", "ether_ros.cli.main", "sim", *config, *self.extra,
                "--interface", self.interface, "--control", str(self.control)]  # fmt: skip
        self.proc = subprocess.Popen(
            netns_command(self.netns, argv),
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            env={**os.environ, "PYTHONUNBUFFERED": "1"},
        )
        assert self.proc.stdout is not None
        sel = selectors.DefaultSelector()
        sel.register(self.proc.stdout, selectors.EVENT_READ)
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if sel.select(timeout=0.2):
                line = self.proc.stdout.readline()
                if line:
                    self.ready_line = line.strip()
                    sel.close()
                    return self
            if self.proc.poll() is not None:
                break
        sel.close()
        err = self.stop()
        raise EtherRosError(f"simulator did not become ready: {err.strip() or 'no output'}")

    def request(self, payload: dict[str, Any]) -> Any:
        return request(self.control, payload)

    def fault(self, kind: str, **args: Any) -> None:
        self.request({"op": "fault", "kind": kind, **args})

    def stop(self) -> str:
        """SIGTERM the simulator, wait for it, and return its stderr."""
        if self.proc is None:
            return ""
        proc, self.proc = self.proc, None
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
            try:
                proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
        err = proc.stderr.read() if proc.stderr is not None else ""
        for stream in (proc.stdout, proc.stderr):
            if stream is not None:
                stream.close()
        self.returncode = proc.returncode
        return err

    def __enter__(self) -> SimProcess:
        return self.start(self.ready_timeout) if self.proc is None else self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.stop()


@dataclass
class CycleStats:
    cycles: int = 0
    wkc_errors: int = 0  # cycles whose working counter was not the expected one
    lost: int = 0  # cycles with no frame back (wkc <= 0)
    wkc_seen: dict[int, int] = field(default_factory=dict)


class SoemBus:
    """A pysoem master on ``interface`` for the slaves of ``cfg``; ``netns``: the network
    namespace the interface lives in (its socket is opened there, ``ether_ros.netns``)."""

    def __init__(
        self,
        cfg: BusConfig,
        interface: str,
        receive_timeout_us: int = 2000,
        netns: str | None = None,
    ) -> None:
        import pysoem

        self.pysoem = pysoem
        self.cfg = cfg
        self.slaves_cfg = bus_order(cfg)
        self.layouts: list[ProcessLayout] = [s.layout for s in self.slaves_cfg]
        self.master = pysoem.Master()
        with thread_in_netns(netns):
            self.master.open(interface)
        self.stats = CycleStats()
        self.cycle_s = cfg.bus.cycle_us / 1e6
        self.receive_timeout_us = receive_timeout_us

    def close(self) -> None:
        self.master.close()

    @property
    def slaves(self) -> list[Any]:
        return list(self.master.slaves)

    def scan(self) -> int:
        """``config_init``: count the slaves and read their SII."""
        n = self.master.config_init()
        if n <= 0:
            raise BusError(f"pysoem found no slaves (config_init returned {n})")
        return int(n)

    def configure(self, dc: bool | None = None) -> int:
        """DC, SYNC0 and PDO mapping; ends in SAFEOP. Returns the size of the IO map."""
        dc = self.cfg.bus.dc.enabled if dc is None else dc
        cycle_ns = self.cfg.bus.cycle_us * 1000
        shift_ns = int(self.cfg.bus.dc.sync0_shift_us * 1000)
        if dc:
            self.master.config_dc()
        for i, slave in enumerate(self.master.slaves):
            # pysoem calls setup_func(slave) in config_map, in PREOP, just before the slave's
            # PDO mapping is read and PREOP->SAFEOP is requested: the place for the PDO
            # assignment and SDO init of the config, and for SYNC0 (a slave that requires DC
            # refuses SAFEOP without it).
            slave.setup_func = _preop_hook(self.slaves_cfg[i], dc, cycle_ns, shift_ns)
        size = int(self.master.config_map())
        state = self.master.state_check(SAFEOP, 500_000)
        if state != SAFEOP:
            self.master.read_state()
            detail = ", ".join(
                f"{s.name}: state {s.state:#x} AL {s.al_status:#06x}" for s in self.master.slaves
            )
            raise BusError(f"slaves did not reach SAFEOP ({detail})")
        self.master.read_state()  # refresh every slave's state, not only the group's
        return size

    def set_watchdog(self, ms: float) -> None:
        """Process-data watchdog of every slave (ESC default 100 ms). Tests that must not trip
        it on a VM hiccup lengthen it; the watchdog test keeps the default."""
        for slave in self.master.slaves:
            slave.set_watchdog("processdata", ms)

    def cycle(self) -> int:
        """One process-data exchange; returns the working counter."""
        self.master.send_processdata()
        wkc = int(self.master.receive_processdata(self.receive_timeout_us))
        st = self.stats
        st.cycles += 1
        st.wkc_seen[wkc] = st.wkc_seen.get(wkc, 0) + 1
        if wkc != self.master.expected_wkc:
            st.wkc_errors += 1
            if wkc <= 0:
                st.lost += 1
        return wkc

    def run(self, seconds: float, each: Callable[[int], None] | None = None) -> None:
        """Cycle for ``seconds`` at the configured cycle time (best effort from Python)."""
        period = max(self.cycle_s, 0.0004)
        next_t = time.perf_counter()
        end = next_t + seconds
        n = 0
        while next_t < end:
            if each is not None:
                each(n)
            self.cycle()
            n += 1
            next_t += period
            delay = next_t - time.perf_counter()
            if delay > 0:
                time.sleep(delay)
            elif delay < -0.05:
                next_t = time.perf_counter()  # fell far behind (VM hiccup): don't burst

    def request_op(self, timeout_s: float = 5.0) -> bool:
        """Cycle while asking every slave for OP; True when all are in OP."""
        self.cycle()
        self.master.state = OP
        self.master.write_state()
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            self.run(0.02)
            if self.master.state_check(OP, 1000) == OP:
                return True
        self.master.read_state()
        return False

    def states(self) -> list[tuple[int, int]]:
        """(AL state, AL status code) of every slave, read from the bus now."""
        self.master.read_state()
        return [(int(s.state), int(s.al_status)) for s in self.master.slaves]

    def set_outputs(self, index: int, values: Mapping[str, object]) -> None:
        slave = self.master.slaves[index]
        slave.output = bytes(self.layouts[index].pack_outputs(values, base=bytes(slave.output)))

    def inputs(self, index: int) -> dict[str, Any]:
        return self.layouts[index].unpack(bytes(self.master.slaves[index].input), "input")


def _preop_hook(
    slave_cfg: SlaveConfig, dc: bool, cycle_ns: int, shift_ns: int
) -> Callable[[Any], None]:
    assign = slave_cfg.pdo_assign

    def hook(slave: Any) -> None:
        if assign is not None:
            for sm_index, pdos in ((coe.RXPDO_ASSIGN, assign.rx), (coe.TXPDO_ASSIGN, assign.tx)):
                if pdos is None:
                    continue
                slave.sdo_write(sm_index, 0, bytes([0]))
                for sub, pdo in enumerate(pdos, start=1):
                    slave.sdo_write(sm_index, sub, pdo.to_bytes(2, "little"))
                slave.sdo_write(sm_index, 0, bytes([len(pdos)]))
        for init in slave_cfg.sdo_init:
            slave.sdo_write(init.index, init.subindex, init.data)
        if dc and slave_cfg.esi.dc_supported:
            slave.dc_sync(True, cycle_ns, shift_ns)

    return hook


# ---- the trot of thesis Table 6.1 -----------------------------------------------------------

# Slave-name prefix → leg of Table 6.1; a name that matches none is driven as front right.
_LEG_BY_PREFIX = {"front_left": "FL", "front_right": "FR", "hind_left": "HL", "hind_right": "HR"}


def table_6_1(
    slave_name: str, a_cm: int = TROT_A_CM, b_cm: int = TROT_B_CM, transition_s: int = 3
) -> dict[str, int]:
    """Output values of Table 6.1 for a leg (matched by name prefix), State_Machine 1."""
    leg = next((v for k, v in _LEG_BY_PREFIX.items() if slave_name.startswith(k)), "FR")
    return leg_outputs(leg, a_cm, b_cm, transition_s)


@dataclass
class TrackStats:
    samples: int = 0
    sq_err: float = 0.0  # sum of squared (measured - desired), deg^2, hip and knee
    desired_min: float = math.inf
    desired_max: float = -math.inf

    def add(self, measured: float, desired: float) -> None:
        self.samples += 1
        self.sq_err += (measured - desired) ** 2
        self.desired_min = min(self.desired_min, desired)
        self.desired_max = max(self.desired_max, desired)

    @property
    def rms_deg(self) -> float:
        return math.sqrt(self.sq_err / self.samples) if self.samples else math.nan

    @property
    def desired_span_deg(self) -> float:
        return self.desired_max - self.desired_min if self.samples else 0.0
