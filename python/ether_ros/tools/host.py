"""Read and write a Linux host's tunables through a configurable root directory.

`rt check` and `rt setup` never touch ``/proc`` or ``/sys`` directly: every path goes through a
:class:`Host`, whose root is ``/`` on a real machine and a fixture tree in tests. The same code
therefore runs against ``tests/data/rt/stock`` and against the machine it runs on.
"""

from __future__ import annotations

import errno
import os
import re
import subprocess
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

from ether_ros.errors import EtherRosError


class HostError(EtherRosError):
    """The host cannot be inspected or changed as asked: names the path or setting."""


def parse_cpu_list(text: str) -> set[int]:
    """``"0-2,5"`` → {0, 1, 2, 5}. Empty text (or "(null)") is the empty set."""
    cpus: set[int] = set()
    text = text.strip()
    if not text or text == "(null)":
        return cpus
    for part in text.split(","):
        part = part.strip()
        if not part:
            continue
        # Kernel syntax also allows "0-7:2/4" (stride); keep the range part only when present.
        part = part.split(":", 1)[0]
        if "-" in part:
            lo, hi = part.split("-", 1)
            if not (lo.isdigit() and hi.isdigit()):
                raise HostError(f"not a CPU list: {text!r}")
            cpus.update(range(int(lo), int(hi) + 1))
        elif part.isdigit():
            cpus.add(int(part))
        else:
            raise HostError(f"not a CPU list: {text!r}")
    return cpus


def format_cpu_list(cpus: Iterable[int]) -> str:
    """{0, 1, 2, 5} → ``"0-2,5"``."""
    ordered = sorted(set(cpus))
    parts: list[str] = []
    i = 0
    while i < len(ordered):
        j = i
        while j + 1 < len(ordered) and ordered[j + 1] == ordered[j] + 1:
            j += 1
        parts.append(str(ordered[i]) if i == j else f"{ordered[i]}-{ordered[j]}")
        i = j + 1
    return ",".join(parts)


def parse_cpu_mask(text: str) -> set[int]:
    """A hex mask as in ``rps_cpus`` (``"00000000,0000000c"``) → {2, 3}."""
    cleaned = text.strip().replace(",", "")
    if not cleaned:
        return set()
    try:
        value = int(cleaned, 16)
    except ValueError as exc:
        raise HostError(f"not a CPU mask: {text!r}") from exc
    return {bit for bit in range(value.bit_length()) if value >> bit & 1}


def format_cpu_mask(cpus: Iterable[int]) -> str:
    value = 0
    for cpu in cpus:
        value |= 1 << cpu
    return f"{value:x}"


def parse_cmdline(text: str) -> dict[str, str]:
    """Kernel command line → {parameter: value} ("" for flags). Later duplicates win."""
    params: dict[str, str] = {}
    for token in text.split():
        if token == "--":
            break  # what follows belongs to init, not to the kernel
        key, _, value = token.partition("=")
        params[key] = value
    return params


@dataclass(frozen=True)
class ThreadSched:
    pid: int
    comm: str
    policy: int  # 0 OTHER, 1 FIFO, 2 RR, 3 BATCH, 5 IDLE, 6 DEADLINE
    rt_priority: int


POLICY_NAMES = {
    0: "SCHED_OTHER",
    1: "SCHED_FIFO",
    2: "SCHED_RR",
    3: "SCHED_BATCH",
    5: "SCHED_IDLE",
    6: "SCHED_DEADLINE",
}


class Host:
    """A view of a host's ``/proc`` and ``/sys`` under ``root``."""

    def __init__(self, root: str | Path = "/") -> None:
        self.root = Path(root)
        if not self.root.is_dir():
            raise HostError(f"host root {str(self.root)!r} does not exist or is not a directory")
        self.is_live = self.root.resolve() == Path("/")

    def path(self, path: str) -> Path:
        return self.root / path.lstrip("/")

    def read(self, path: str) -> str | None:
        """The file's text, or None when it does not exist or cannot be read."""
        try:
            return self.path(path).read_text(errors="replace")
        except OSError:
            return None

    def read_strip(self, path: str) -> str | None:
        text = self.read(path)
        return None if text is None else text.strip()

    def exists(self, path: str) -> bool:
        return self.path(path).exists()

    def glob(self, pattern: str) -> list[str]:
        """Absolute host paths (as seen from the root) matching ``pattern``."""
        base = self.root
        found = sorted(base.glob(pattern.lstrip("/")))
        return ["/" + str(p.relative_to(base)) for p in found]

    def write(self, path: str, value: str) -> None:
        target = self.path(path)
        try:
            with open(target, "w") as fh:
                fh.write(value)
        except OSError as exc:
            reason = os.strerror(exc.errno) if exc.errno else str(exc)
            raise HostError(f"cannot write {value!r} to {path}: {reason}") from exc

    def mkdir(self, path: str) -> None:
        try:
            self.path(path).mkdir()
        except OSError as exc:
            raise HostError(f"cannot create {path}: {os.strerror(exc.errno or 0)}") from exc

    def rmdir(self, path: str) -> None:
        target = self.path(path)
        try:
            target.rmdir()
        except OSError as exc:
            if exc.errno != errno.ENOTEMPTY or self.is_live:
                raise HostError(f"cannot remove {path}: {os.strerror(exc.errno or 0)}") from exc
            # A fixture tree holds the control files as ordinary files; a cgroupfs directory
            # removes them itself.
            for child in target.iterdir():
                child.unlink()
            target.rmdir()

    # ---- composite views -------------------------------------------------------------------

    def cmdline(self) -> dict[str, str]:
        return parse_cmdline(self.read("/proc/cmdline") or "")

    def online_cpus(self) -> set[int]:
        text = self.read_strip("/sys/devices/system/cpu/online")
        if text is not None:
            return parse_cpu_list(text)
        return {
            int(m.group(1))
            for p in self.glob("sys/devices/system/cpu/cpu[0-9]*")
            if (m := re.search(r"cpu(\d+)$", p))
        }

    def interface_irqs(self, interface: str) -> dict[int, str]:
        """IRQ number → action name for every /proc/interrupts line naming the interface.

        Drivers name their vectors after the interface (``enp5s0``, ``enp5s0-rx-0``,
        ``enp5s0-TxRx-1``); a virtual interface (veth) has none.
        """
        irqs: dict[int, str] = {}
        text = self.read("/proc/interrupts") or ""
        pattern = re.compile(rf"(^|[\s,]){re.escape(interface)}($|[-_:,\s])")
        for line in text.splitlines()[1:]:
            head, _, rest = line.partition(":")
            if not head.strip().isdigit():
                continue
            name = rest.split()[-1] if rest.split() else ""
            if pattern.search(" " + rest.strip()):
                irqs[int(head)] = name
        return irqs

    def all_irqs(self) -> list[int]:
        return sorted(int(p.rsplit("/", 1)[1]) for p in self.glob("proc/irq/[0-9]*"))

    def set_sched(self, pid: int, policy: int, priority: int) -> None:
        """Set a thread's scheduling policy and real-time priority (a fixture tree gets the
        two fields of its ``stat`` file rewritten, as the kernel would report them)."""
        if self.is_live:
            try:
                os.sched_setscheduler(pid, policy, os.sched_param(priority))
            except OSError as exc:
                raise HostError(
                    f"cannot set the scheduling of pid {pid}: {os.strerror(exc.errno or 0)}"
                ) from exc
            return
        path = f"/proc/{pid}/stat"
        stat = self.read(path)
        if stat is None:
            raise HostError(f"no process {pid} under {self.root}")
        close = stat.rfind(")")
        fields = stat[close + 2 :].split()
        fields[37], fields[38] = str(priority), str(policy)
        self.write(path, stat[: close + 2] + " ".join(fields) + "\n")

    def holders(self, device: str) -> list[int]:
        """Processes with ``device`` open (their ``/proc/PID/fd`` links point at it)."""
        pids: set[int] = set()
        for fd in self.glob("proc/[0-9]*/fd/*"):
            try:
                target = os.readlink(self.path(fd))
            except OSError:
                continue  # gone, or not ours to look at
            if target == device:
                pids.add(int(fd.split("/")[2]))
        return sorted(pids)

    def threads(self) -> list[ThreadSched]:
        """Every process in /proc with its scheduling policy and real-time priority."""
        result: list[ThreadSched] = []
        for proc in self.glob("proc/[0-9]*"):
            stat = self.read(f"{proc}/stat")
            if not stat:
                continue
            # comm is in parentheses and may contain spaces; the fields after it are fixed.
            close = stat.rfind(")")
            comm = stat[stat.find("(") + 1 : close]
            fields = stat[close + 2 :].split()
            # fields[0] is field 3 (state); rt_priority is field 40, policy field 41.
            if len(fields) < 39:
                continue
            result.append(
                ThreadSched(int(proc.rsplit("/", 1)[1]), comm, int(fields[38]), int(fields[37]))
            )
        return result


@dataclass
class Coalesce:
    """The interrupt-coalescing settings that matter for latency (None: not reported)."""

    supported: bool
    values: dict[str, str]


class Ethtool:
    """``ethtool -c`` / ``-C`` on the live host (argument lists only, never a shell)."""

    def __init__(self, host: Host) -> None:
        self.host = host

    def _fixture_file(self, interface: str) -> Path:
        return self.host.path(f"ethtool/{interface}.coalesce")

    def get(self, interface: str) -> Coalesce | None:
        """Current settings, or None when ethtool (or its fixture file) is not available."""
        if not self.host.is_live:
            fixture = self._fixture_file(interface)
            if not fixture.exists():
                return None
            return parse_ethtool_coalesce(fixture.read_text())
        try:
            out = subprocess.run(
                ["ethtool", "-c", interface], capture_output=True, text=True, timeout=5, check=False
            )
        except (OSError, subprocess.TimeoutExpired):
            return None
        if out.returncode != 0:
            if "not supported" in (out.stderr + out.stdout).lower():
                return Coalesce(False, {})
            return None
        return parse_ethtool_coalesce(out.stdout)

    def set(self, interface: str, values: dict[str, str]) -> None:
        if not values:
            return
        if not self.host.is_live:
            fixture = self._fixture_file(interface)
            current = parse_ethtool_coalesce(fixture.read_text()).values
            current.update(values)
            fixture.write_text(format_ethtool_coalesce(interface, current))
            return
        argv = ["ethtool", "-C", interface]
        for key, value in values.items():
            argv += [key, value]
        try:
            out = subprocess.run(argv, capture_output=True, text=True, timeout=5, check=False)
        except (OSError, subprocess.TimeoutExpired) as exc:
            raise HostError(f"ethtool -C {interface} failed: {exc}") from exc
        # ethtool exits 80 when nothing changed; that is success for us.
        if out.returncode not in (0, 80):
            reason = (out.stderr or out.stdout).strip().splitlines()
            raise HostError(f"ethtool -C {interface} failed: {reason[-1] if reason else '?'}")


# The settings `rt setup` turns off and `rt check` looks at, by their ethtool names.
COALESCE_KEYS = ("adaptive-rx", "adaptive-tx", "rx-usecs", "rx-frames", "tx-usecs", "tx-frames")


def parse_ethtool_coalesce(text: str) -> Coalesce:
    values: dict[str, str] = {}
    for line in text.splitlines():
        if "Adaptive RX:" in line:
            # "Adaptive RX: off  TX: off"
            m = re.search(r"Adaptive RX:\s*(\S+)\s+TX:\s*(\S+)", line)
            if m:
                values["adaptive-rx"], values["adaptive-tx"] = m.group(1), m.group(2)
            continue
        key, sep, value = line.partition(":")
        key = key.strip()
        if sep and key in COALESCE_KEYS:
            values[key] = value.strip()
    return Coalesce(True, values)


def format_ethtool_coalesce(interface: str, values: dict[str, str]) -> str:
    """The text ``ethtool -c`` prints for these values (what a fixture file holds)."""
    lines = [f"Coalesce parameters for {interface}:"]
    if "adaptive-rx" in values or "adaptive-tx" in values:
        lines.append(
            f"Adaptive RX: {values.get('adaptive-rx', 'n/a')}  "
            f"TX: {values.get('adaptive-tx', 'n/a')}"
        )
    lines += [f"{k}: {v}" for k, v in values.items() if not k.startswith("adaptive")]
    return "\n".join(lines) + "\n"
