"""A bus configuration made from one ESI file: N slaves of one device, nothing else to write.

``ether-ros sim --esi FILE`` runs such a bus on the simulator, and the master opens the same bus
with ``Bus.open(bus_config_for_esi(FILE), interface=...)``. Both sides build the config the same
way, so they agree on the slaves without a YAML file. The config goes through
:func:`load_bus_config` like any other: one validation path.
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import yaml

from ether_ros.config.bus import BusConfig, load_bus_config
from ether_ros.config.esi import EsiDevice, load_esi
from ether_ros.errors import ConfigError

MAX_COUNT = 64


def pick_device(path: Path, device: str | None) -> EsiDevice:
    """The device ``device`` (a ``<Type>`` name; newest revision) of the ESI at ``path``, or
    its only device type when ``device`` is None."""
    devices = load_esi(path)
    types = sorted({d.type_name for d in devices})
    if device is None:
        if len(types) > 1:
            raise ConfigError(f"{path}: holds several devices ({', '.join(types)}): give --device")
        device = types[0]
    matches = [d for d in devices if d.type_name == device]
    if not matches:
        raise ConfigError(f"{path}: no device {device!r} (it has: {', '.join(types)})")
    return max(matches, key=lambda d: d.revision)


def bus_config_for_esi(
    path: str | Path,
    device: str | None = None,
    count: int = 1,
    *,
    interface: str | None = None,
    cycle_us: int = 1000,
) -> BusConfig:
    """A validated bus of ``count`` slaves of ``device`` from the ESI at ``path``, named
    ``<type>_<n>``, at ``cycle_us``; with DC (SYNC0 at the cycle) when the device needs it."""
    file = Path(path).resolve()
    if not 1 <= count <= MAX_COUNT:
        raise ConfigError(f"--count must be 1..{MAX_COUNT}, got {count}")
    dev = pick_device(file, device)
    base = "".join(c if c.isalnum() else "_" for c in dev.type_name.lower()).strip("_") or "slave"
    if not base[0].isalpha():
        base = f"s_{base}"
    data = {
        "bus": {
            "name": f"{base}_bus",
            "cycle_us": cycle_us,
            "dc": {"enabled": dev.dc_required},
        },
        "esi": [str(file)],
        "slaves": [
            {
                "name": f"{base}_{n}",
                "position": n,
                "device": dev.type_name,
                "revision": dev.revision,
            }
            for n in range(count)
        ],
    }
    with tempfile.TemporaryDirectory(prefix="ether_ros_esi_") as tmp:
        yml = Path(tmp) / f"{base}.yaml"
        yml.write_text(yaml.safe_dump(data, sort_keys=False))
        return load_bus_config(yml, interface=interface)
