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
#: Slaves on a bus made from several devices (``bus_config_for_devices``).
MAX_BUS_SLAVES = 512


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


def slave_name(device: EsiDevice, taken: set[str]) -> str:
    """A config identifier for a slave of ``device``: its type (and revision when needed)
    lower-cased, letters, digits and underscores, unique among ``taken``."""
    base = "".join(c if c.isalnum() else "_" for c in device.type_name.lower()).strip("_")
    base = base or "slave"
    if not base[0].isalpha():
        base = f"s_{base}"
    base = base[:40]
    name = base
    if name in taken:
        name = f"{base}_r{device.revision:x}"[:55]
    k = 2
    while name in taken:
        name = f"{base}_{k}"
        k += 1
    taken.add(name)
    return name


def bus_yaml_for_devices(
    devices: list[EsiDevice],
    yml: Path,
    *,
    cycle_us: int = 1000,
    name: str = "esi_bus",
) -> Path:
    """Write the bus configuration of one slave per device of ``devices`` (a line, in the
    given order; each slave names its device by type and revision, its ESI file listed) to
    ``yml``. DC is on when a device needs it. Both the simulator (``ether-ros sim YML``) and
    the master open the bus from that one file."""
    if not 1 <= len(devices) <= MAX_BUS_SLAVES:
        raise ConfigError(f"a bus of 1..{MAX_BUS_SLAVES} devices, got {len(devices)}")
    for d in devices:
        if d.passive:
            raise ConfigError(f"{d.source}: {d.type_name} is a passive terminal, not on the bus")
    files = sorted({str(Path(d.source).resolve()) for d in devices})
    taken: set[str] = set()
    data = {
        "bus": {
            "name": name,
            "cycle_us": cycle_us,
            "dc": {"enabled": any(d.dc_required for d in devices)},
        },
        "esi": files,
        "slaves": [
            {
                "name": slave_name(d, taken),
                "position": n,
                "device": d.type_name,
                "vendor_id": d.vendor_id,
                "product_code": d.product_code,
                "revision": d.revision,
            }
            for n, d in enumerate(devices)
        ],
    }
    yml.write_text(yaml.safe_dump(data, sort_keys=False))
    return yml
