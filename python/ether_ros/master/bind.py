"""The configured slaves bound to the ones found on the wire (IgH attaches each
``slave_config`` to a found slave the same way): the tree and the identities checked (naming
the configured slave that is missing, the one found that is not configured, and a different
device in a slave's place: configured and found identity), then each configured slave's
``Slave`` with its DC role, the process image laid out, and the engine plan built from the
setup (``plan.py`` does the layout and the plan; this module only calls it).
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass

from ether_ros import _native
from ether_ros.config.process import ProcessValueError
from ether_ros.errors import BusError, ConfigError
from ether_ros.master import axis as axis_mod
from ether_ros.master.dc import DcSlave
from ether_ros.master.found import FoundSlave
from ether_ros.master.plan import DcPlan, ImageLayout, ImageSlave, build_plan, layout_image
from ether_ros.master.scan import bus_tree, match_configuration, match_topology
from ether_ros.master.setup import BusSetup, SlaveSetup
from ether_ros.master.slave import Slave
from ether_ros.topology import Link, line

log = logging.getLogger(__name__)


def check_found(setup: BusSetup, found: Sequence[FoundSlave]) -> tuple[list[Link], list[int]]:
    """The tree of ``found``, checked against the configured one when the configuration
    describes it, then the identities; returns the tree and each configured slave's position."""
    try:
        tree = bus_tree(found)
    except BusError as exc:
        if setup.declares_topology:
            raise
        # A configuration of a line does not depend on the ports: carry on as one.
        log.warning("%s; taking the bus for a line", exc)
        tree = line(len(found))
    if setup.declares_topology:
        names = [s.name for s in setup.config.by_position()]
        match_topology(tree, list(setup.tree), names)
    return tree, match_configuration(found, [s.expected for s in setup.slaves])


@dataclass
class Bound:
    """The bus as bound: slaves in bus order, the tree, the DC reference, the image layout and
    its safe output image."""

    slaves: list[Slave]
    tree: list[Link]
    dc_reference: Slave | None
    layout: ImageLayout
    safe: bytes


def bind(setup: BusSetup, found: Sequence[FoundSlave]) -> Bound:
    tree, positions = check_found(setup, found)
    slaves = [_slave(cfg, found[pos]) for cfg, pos in zip(setup.slaves, positions, strict=True)]
    slaves.sort(key=lambda s: s.position)
    reference = _dc_roles(setup, slaves)
    by_name = {s.name: s for s in setup.slaves}
    layout = layout_image(
        [_image_slave(by_name[s.name], s) for s in slaves],
        groups=list(setup.group_cycles),
        dc=reference is not None,
    )
    for s, area in zip(slaves, layout.slaves, strict=True):
        s.area = area
    return Bound(slaves, tree, reference, layout, _safe_image(setup, slaves, layout))


def rebind(setup: BusSetup, slaves: Sequence[Slave], found: Sequence[FoundSlave]) -> None:
    """After a new scan (slaves may have been power-cycled since ``open``): the same bus, each
    slave's found part renewed."""
    _tree, positions = check_found(setup, found)
    by_name = {s.name: s for s in slaves}
    for cfg, pos in zip(setup.slaves, positions, strict=True):
        s = by_name[cfg.name]
        s.found = found[pos]
        s.lost = False


def _slave(cfg: SlaveSetup, found: FoundSlave) -> Slave:
    return Slave(
        name=cfg.name,
        position=found.position,
        station=found.station,
        found=found,
        config=cfg.config,
        device=cfg.device,
        selection=cfg.selection,
        layout=cfg.layout,
        setup=cfg,
    )


def _image_slave(cfg: SlaveSetup, s: Slave) -> ImageSlave:
    """What the image layout needs of ``s``: sizes, group, and whether it takes LRW (not when
    its ESC says LRW is unsupported, nor when the config asks for LRD + LWR)."""
    return ImageSlave(
        s.position,
        s.station,
        s.name,
        s.layout.output_bytes if s.layout else 0,
        s.layout.input_bytes if s.layout else 0,
        cfg.group,
        s.found.lrw_supported and cfg.lrw,
    )


def _dc_roles(setup: BusSetup, slaves: Sequence[Slave]) -> Slave | None:
    if not setup.dc_enabled:
        return None
    capable = [s for s in slaves if s.found.dc_supported]
    if not capable:
        raise BusError("distributed clocks are enabled but no slave supports them")
    reference = capable[0]
    if setup.dc_reference is not None and setup.dc_reference != reference.position:
        raise BusError(
            f"DC reference clock must be the first DC-capable slave "
            f"(slave {reference.position}, {reference.name}); configured: {setup.dc_reference}"
        )
    for s in capable:
        aa = s.device.assign_activate if s.device is not None else 0
        if s.device is None and s.found.header.dc:
            aa = next((m.assign_activate for m in s.found.header.dc if m.assign_activate), 0)
        every = setup.slave(s.name).group_every
        s.dc = DcSlave(
            s.position, s.station, s.name, assign_activate=aa,
            sync0_cycle_ns=every * setup.cycle_ns,
        )  # fmt: skip
    return reference


def _safe_image(setup: BusSetup, slaves: Sequence[Slave], layout: ImageLayout) -> bytes:
    image = bytearray(layout.output_bytes)
    for s in slaves:
        if s.layout is None or s.area is None or not s.area.output_bytes:
            continue
        try:
            area = s.layout.pack_outputs(dict(setup.slave(s.name).safe_outputs))
        except ProcessValueError as exc:
            raise ConfigError(f"slaves.{s.name}.safe_outputs: {exc}") from None
        image[s.area.output_offset : s.area.output_offset + s.area.output_bytes] = area
    return bytes(image)


def engine_plan(
    setup: BusSetup,
    bound: Bound,
    time_offset_ns: int,
    initial_outputs: bytes,
) -> _native.Plan:
    """The plan ``Engine.start_cyclic`` takes, from the setup and the bound bus."""
    dc = DcPlan()
    if bound.dc_reference is not None:
        dc = DcPlan(
            mode=setup.dc_mode,
            reference_station=bound.dc_reference.station,
            time_offset_ns=time_offset_ns,
            sync0_shift_ns=setup.sync0_shift_ns,
        )
    return build_plan(
        bound.layout,
        cycle_ns=setup.cycle_ns,
        order=setup.cycle_order,
        safe_outputs=bound.safe,
        initial_outputs=initial_outputs,
        dc=dc,
        rt=setup.rt,
        watchdog_ns=setup.watchdog_ns,
        axes=axis_mod.plan_entries(list(setup.axes), bound.layout),
        group_watchdog_ns=dict(setup.group_watchdog_ns),
    )
