"""Rigs shared by the master's unit tests: a shipped bus configuration relaxed for the
in-process link to the real simulator, a ``Bus`` open on its simulated network, and a fake wire
that records the frames the acyclic worker (or the shared frames) hand it."""

from __future__ import annotations

import contextlib
import threading
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

from ether_ros.config import load_bus_config
from ether_ros.config.bus import BusConfig
from ether_ros.errors import LinkError
from ether_ros.master import Bus
from ether_ros.master.datagrams import Cmd

CONFIG_DIR = Path(__file__).resolve().parent.parent / "config"

Datagram = tuple[int, int, bytes | int]


def relaxed_config(config: str | Path = "laelaps.yaml") -> BusConfig:
    """``config/<config>`` (or a path) for the in-process link: it takes the GIL per frame, so
    a relaxed cycle (2 ms), no real-time policy, no memory locking, no command watchdog."""
    cfg = load_bus_config(config if isinstance(config, Path) else CONFIG_DIR / config)
    cfg.bus.cycle_us = 2000
    cfg.bus.realtime.policy = "other"
    cfg.bus.realtime.cpu = None
    cfg.bus.realtime.lock_memory = False
    cfg.bus.watchdog_ms = 0
    return cfg


def sim_network(cfg: BusConfig) -> Any:
    """The simulated network of ``cfg`` (in-process: no root, no interface)."""
    from ether_ros.sim.network import build_network

    return build_network(cfg)


@contextlib.contextmanager
def sim_bus(config: str | BusConfig = "laelaps.yaml") -> Iterator[tuple[Bus, Any]]:
    """A ``Bus`` open on the simulated network of ``config`` (a name in ``config/`` relaxed by
    ``relaxed_config``, or a configuration), and the network (to inject faults); closed after."""
    cfg = relaxed_config(config) if isinstance(config, str) else config
    net = sim_network(cfg)
    with Bus.open(cfg, link=net, drift_frames=100) as bus:
        yield bus, net


class RecordingWire:
    """A transport for the acyclic worker that records every frame it is given. FPRD answers
    the station's low byte in every byte, any other command wkc 1 (a write echoes its data);
    a ``silent`` station never answers (wkc 0, as a slave whose mailbox stays empty); a frame
    with a datagram for ``fail_station`` raises ``LinkError`` (a lost frame)."""

    def __init__(self, silent: int | None = None, fail_station: int | None = None) -> None:
        self.silent = silent
        self.fail_station = fail_station
        self.frames: list[list[Datagram]] = []
        self.lock = threading.Lock()

    def transact(
        self, datagrams: Sequence[Datagram], timeout_us: int = 0, retries: int = 0
    ) -> list[tuple[bytes, int]]:
        with self.lock:
            self.frames.append(list(datagrams))
        out = []
        for cmd, address, payload in datagrams:
            station = address & 0xFFFF
            n = payload if isinstance(payload, int) else len(payload)
            if station == self.fail_station:
                raise LinkError("no answer")
            if station == self.silent:
                out.append((bytes(n), 0))
            elif cmd == Cmd.FPRD:
                out.append((bytes([station & 0xFF]) * n, 1))
            else:
                out.append((bytes(payload) if isinstance(payload, bytes) else b"", 1))
        return out
