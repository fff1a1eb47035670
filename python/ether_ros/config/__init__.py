"""Bus configuration (YAML) and device descriptions (ESI XML), parsed into typed models.

Public API:

- :func:`load_bus_config` → :class:`BusConfig` (slaves resolved to their ESI devices and
  process layouts)
- :func:`load_esi` → list of :class:`EsiDevice`
- :func:`build_sii` / :func:`parse_sii` (:class:`SiiInfo`)
- :class:`ProcessLayout` / :class:`ProcessVariable` (bit offsets, types, value codec)
"""

from ether_ros.config.bus import (
    BusConfig,
    BusSection,
    DcConfig,
    Joint,
    PdoAssign,
    RealtimeConfig,
    RosConfig,
    SdoInit,
    SimConfig,
    SlaveConfig,
    load_bus_config,
)
from ether_ros.config.esi import (
    DcOpMode,
    EsiDevice,
    MailboxDesc,
    OdEntry,
    OdObject,
    Pdo,
    PdoEntry,
    SyncManagerDesc,
    load_esi,
    load_esi_paths,
)
from ether_ros.config.process import ProcessLayout, ProcessValueError, ProcessVariable
from ether_ros.config.sii import SiiInfo, build_sii, parse_sii

__all__ = [
    "BusConfig",
    "BusSection",
    "DcConfig",
    "DcOpMode",
    "EsiDevice",
    "Joint",
    "MailboxDesc",
    "OdEntry",
    "OdObject",
    "Pdo",
    "PdoAssign",
    "PdoEntry",
    "ProcessLayout",
    "ProcessValueError",
    "ProcessVariable",
    "RealtimeConfig",
    "RosConfig",
    "SdoInit",
    "SiiInfo",
    "SimConfig",
    "SlaveConfig",
    "SyncManagerDesc",
    "build_sii",
    "load_bus_config",
    "load_esi",
    "load_esi_paths",
    "parse_sii",
]
