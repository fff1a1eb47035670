"""Open a standalone bus for a tool: load the configuration, open the interface, bring it up.

Every tool that drives a bus itself (record, top, experiments) goes through :func:`running_bus`
so they all stop the bus (safe outputs, SAFEOP, INIT) and close the link on the way out, also on
Ctrl-C.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any


def load_config(path: str, interface: str | None = None, link: str | None = None) -> Any:
    from ether_ros.config import load_bus_config

    return load_bus_config(path, interface=interface, link=link)


@contextmanager
def running_bus(
    config: Any, interface: str | None = None, start: bool = True, link: Any = None
) -> Iterator[Any]:
    """A :class:`~ether_ros.master.bus.Bus` opened on ``interface`` (or the in-process
    ``link``), in OP when ``start``; stopped and closed when the block ends."""
    from ether_ros.master.bus import Bus

    bus = Bus.open(config, interface=interface, link=link)
    try:
        if start:
            bus.start()
        yield bus
    finally:
        bus.close()
