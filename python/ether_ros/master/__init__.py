"""The master: bring a bus to OP through the engine's datagram service, then run it cyclically.

``from ether_ros.master import Bus`` — see ``docs/master.md``. ``Bus`` is imported lazily so the
lower layers (datagrams, mailbox, CoE) can be used without loading the whole bring-up.
"""

from __future__ import annotations

from typing import Any

__all__ = ["Bus", "BusEvent"]


def __getattr__(name: str) -> Any:
    if name in __all__:
        from ether_ros.master import bus

        # Dynamic by nature: the lazy import of a name of this module (PEP 562).
        return getattr(bus, name)
    raise AttributeError(f"module 'ether_ros.master' has no attribute {name!r}")
