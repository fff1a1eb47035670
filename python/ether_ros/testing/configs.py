"""Variants of the shipped configurations for tests and benchmarks."""

from __future__ import annotations

from pathlib import Path

import yaml

REPO = Path(__file__).resolve().parents[3]


def config_without_lease(name: str, into: Path) -> Path:
    """A copy of config/NAME with the control lease off (docs/security.md), written into
    ``into`` beside a link to the repository's devices/ (the shipped configurations name their
    ESI files relative to themselves)."""
    data = yaml.safe_load((REPO / "config" / name).read_text())
    data.setdefault("ros", {})["lease"] = {"enabled": False}
    return _write(data, into, name.replace(".yaml", "_open.yaml"))


def config_with_watchdog(name: str, into: Path, watchdog_ms: int) -> Path:
    """A copy of config/NAME with the engine's command watchdog at ``watchdog_ms`` (0: off),
    written like ``config_without_lease``. A watchdog trip voids the commands before it (a
    stop's reset does not restart, docs/security.md); the node feeds the watchdog from a
    Python thread, which a loaded 2-core VM can stall for longer than the shipped 100 ms of
    config/laelaps.yaml, so tests that are not about the watchdog give it more room."""
    data = yaml.safe_load((REPO / "config" / name).read_text())
    data["bus"]["watchdog_ms"] = int(watchdog_ms)
    return _write(data, into, name.replace(".yaml", f"_watchdog{int(watchdog_ms)}.yaml"))


def config_with_lease_ttl(name: str, into: Path, ttl_s: float) -> Path:
    """A copy of config/NAME with the control lease on and its time to live at ``ttl_s``,
    written like ``config_without_lease``. The holder must renew within the time to live or
    lose the lease (and motion stops): on a 2-core VM under the load of a flood test the
    renewals of the test's client can stall past the shipped 3 s, which is the lease working,
    not what a test about floods checks."""
    data = yaml.safe_load((REPO / "config" / name).read_text())
    data.setdefault("ros", {})["lease"] = {"enabled": True, "ttl_s": float(ttl_s)}
    return _write(data, into, name.replace(".yaml", f"_ttl{int(ttl_s)}.yaml"))


def _write(data: object, into: Path, filename: str) -> Path:
    (into / "config").mkdir(exist_ok=True)
    if not (into / "devices").exists():
        (into / "devices").symlink_to(REPO / "devices")
    path = into / "config" / filename
    path.write_text(yaml.safe_dump(data))
    return path
