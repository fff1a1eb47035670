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
    (into / "config").mkdir(exist_ok=True)
    if not (into / "devices").exists():
        (into / "devices").symlink_to(REPO / "devices")
    path = into / "config" / name.replace(".yaml", "_open.yaml")
    path.write_text(yaml.safe_dump(data))
    return path
