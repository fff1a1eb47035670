"""Everything the master knows about one configured slave, gathered during discovery."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from ether_ros.config.esi import EsiDevice
from ether_ros.config.process import ProcessLayout
from ether_ros.master.al import SlaveRef
from ether_ros.master.dc import DcSlave
from ether_ros.master.pdo import PdoSelection
from ether_ros.master.plan import SlaveArea
from ether_ros.master.scan import FoundSlave


@dataclass
class Slave:
    name: str
    position: int
    station: int
    found: FoundSlave
    config: Any  # the slave's entry of the bus configuration
    device: EsiDevice | None
    selection: PdoSelection
    layout: ProcessLayout | None
    area: SlaveArea | None = None
    dc: DcSlave | None = None
    mailbox: Any = None  # ether_ros.master.mailbox.Mailbox once the mailbox SMs are set
    sdo: Any = None  # ether_ros.master.coe.SdoClient
    # Supervision: the last AL state seen and whether the slave is out of OP.
    lost: bool = False
    last_problem: str = ""
    recoveries: int = 0
    extra: dict[str, Any] = field(default_factory=dict)

    @property
    def ref(self) -> SlaveRef:
        return SlaveRef(self.position, self.station, self.name)

    @property
    def has_coe(self) -> bool:
        if self.device is not None and self.device.mailbox is not None:
            return self.device.mailbox.coe
        return self.found.header.has_coe

    def __str__(self) -> str:
        return f"slave {self.position} ({self.name})"
