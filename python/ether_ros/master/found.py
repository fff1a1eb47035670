"""The slaves as found on the wire, apart from the configured ones (``setup.py``), as IgH keeps
its ``ec_slave_t`` apart from its ``ec_slave_config_t``.

``FoundSlave`` is what a scan read (station, alias, ESC type and features, DL status with the
open ports, the SII image and its header: identity, mailbox, DC); ``SlaveRuntime`` what
supervision and the slave's state machine learn while the bus runs (AL state, the step the
machine is in, losses and recoveries, the last error).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from ether_ros._native.protocol import features
from ether_ros.config.sii import SiiInfo
from ether_ros.master.al import AlStatus, al_code_text
from ether_ros.topology import open_ports

if TYPE_CHECKING:
    from ether_ros.master.slave import Slave


@dataclass
class FoundSlave:
    """A slave as found on the wire."""

    position: int
    station: int
    alias: int
    esc_type: int
    esc_features: int
    sii: bytes
    header: SiiInfo
    dl_status: int = 0

    @property
    def open_ports(self) -> int:
        """Bit p set when port p has an open link (from DL status 0x0110)."""
        return open_ports(self.dl_status)

    @property
    def vendor_id(self) -> int:
        return self.header.vendor_id

    @property
    def product_code(self) -> int:
        return self.header.product_code

    @property
    def revision(self) -> int:
        return self.header.revision

    @property
    def name(self) -> str:
        """The device name from the SII (general category), or '' when it has none."""
        return self.header.name

    @property
    def dc_supported(self) -> bool:
        return bool(self.esc_features & features.DC)

    @property
    def lrw_supported(self) -> bool:
        return not self.esc_features & features.LRW_NOT_SUPPORTED

    def identity(self) -> str:
        return (
            f"vendor 0x{self.vendor_id:08X} product 0x{self.product_code:08X} "
            f"revision 0x{self.revision:08X}"
        )


@dataclass
class SlaveRuntime:
    """A configured slave's life on the bus: the AL state last seen, the state machine's step
    ('' when it is not running), whether supervision considers it lost and why, how many times
    it came back, and the last error of its machine."""

    al_state: int = 0
    step: str = ""
    lost: bool = False
    last_problem: str = ""
    recoveries: int = 0
    last_error: str = ""


@dataclass(frozen=True)
class SlaveState:
    """A slave's AL state as ``Bus.states`` reports it."""

    name: str
    position: int
    station: int
    state: str
    error: bool
    code: int
    text: str
    problem: str = ""  # why the supervisor considers the slave lost ('' when it is fine)

    def as_dict(self) -> dict[str, Any]:
        return dict(self.__dict__)


def slave_state(s: Slave, st: AlStatus) -> SlaveState:
    text = al_code_text(st.code) if st.error else ""
    problem = s.last_problem if s.lost else ""
    return SlaveState(s.name, s.position, s.station, st.name, st.error, st.code, text, problem)
