"""One configured slave on the bus: what the configuration says (its ESI device, PDO selection
and process layout), the slave found for it on the wire (``found.py``: ``FoundSlave``), its
runtime (``SlaveRuntime``), and what bring-up gave it (image area, DC, mailbox)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from ether_ros.config.esi import EsiDevice
from ether_ros.config.process import ProcessLayout
from ether_ros.master.al import SlaveRef
from ether_ros.master.dc import DcSlave
from ether_ros.master.found import FoundSlave, SlaveRuntime
from ether_ros.master.pdo import PdoSelection
from ether_ros.master.plan import SlaveArea

if TYPE_CHECKING:
    from ether_ros.master.setup import SlaveSetup


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
    # The SDO client as users see it: each call holds the slave's mailbox lock (worker.py).
    sdo: Any = None
    sdo_client: Any = None  # the ether_ros.master.coe.SdoClient itself
    runtime: SlaveRuntime = field(default_factory=SlaveRuntime)
    extra: dict[str, Any] = field(default_factory=dict)
    setup: SlaveSetup | None = None  # the configured slave (setup.py)

    @classmethod
    def unconfigured(cls, found: FoundSlave, device: EsiDevice | None, name: str) -> Slave:
        """A slave found on the wire with no configuration behind it (an inspection: its state
        machine up to PREOP, its mailbox; no process data)."""
        return cls(
            name=name,
            position=found.position,
            station=found.station,
            found=found,
            config=None,
            device=device,
            selection=PdoSelection(),
            layout=None,
        )

    # Supervision's view, kept on the runtime (these names are the API's).
    @property
    def lost(self) -> bool:
        return self.runtime.lost

    @lost.setter
    def lost(self, value: bool) -> None:
        self.runtime.lost = value

    @property
    def last_problem(self) -> str:
        return self.runtime.last_problem

    @last_problem.setter
    def last_problem(self, value: str) -> None:
        self.runtime.last_problem = value

    @property
    def recoveries(self) -> int:
        return self.runtime.recoveries

    @recoveries.setter
    def recoveries(self, value: int) -> None:
        self.runtime.recoveries = value

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
