"""Engine plans for the engine's own tests, built as the master builds them: the typed
contracts of ``ether_ros._native`` (``Plan``, ``Frame``, ``AxisPlan``, ...), which check
themselves when made."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from ether_ros import _native
from ether_ros.config.bus import AxisConfig

#: RT settings of a test run: a normal thread, no memory lock (no root needed).
RT_OTHER: dict[str, Any] = {
    "policy": "other",
    "priority": 0,
    "cpu": None,
    "runtime_ns": 0,
    "lock_memory": False,
}


def rt(**fields: Any) -> _native.RtSettings:
    return _native.RtSettings(**{**RT_OTHER, **fields})


def dc(mode: str = "off", time_offset_ns: int = 0, sync0_shift_ns: int = 0) -> _native.DcSettings:
    return _native.DcSettings(
        mode=mode, time_offset_ns=time_offset_ns, sync0_shift_ns=sync0_shift_ns
    )


def logical(
    kind: str, address: int, length: int, image_offset: int, expected_wkc: int
) -> _native.LogicalDatagram:
    return _native.LogicalDatagram(
        kind=kind,
        address=address,
        length=length,
        image_offset=image_offset,
        expected_wkc=expected_wkc,
    )


def dc_datagrams(mode: str, station: int = 0x1001) -> list[_native.DcDatagram]:
    """The DC datagrams of the first frame for ``mode``."""
    out = [_native.DcDatagram(kind="dc_sync", station=station)]
    if mode == "ref_follows_master":
        out.insert(0, _native.DcDatagram(kind="dc_write_ref", station=station))
    return out


def frame(
    datagrams: Sequence[_native.LogicalDatagram | _native.DcDatagram],
    every: int = 1,
    watchdog_ns: int = 0,
) -> _native.Frame:
    return _native.Frame(datagrams=list(datagrams), every=every, watchdog_ns=watchdog_ns)


def plan(
    datagrams: Sequence[_native.LogicalDatagram | _native.DcDatagram],
    image_len: int,
    **fields: Any,
) -> _native.Plan:
    """A one-frame plan of ``datagrams`` over an image of ``image_len`` bytes; ``fields`` are
    ``Plan``'s own keywords (``frames`` replaces the one frame)."""
    base: dict[str, Any] = {
        "cycle_ns": 1_000_000,
        "order": "send_at_wake",
        "frames": [frame(datagrams)],
        "image_len": image_len,
        "output_ranges": [],
        "initial_image": bytes(image_len),
        "safe_image": bytes(image_len),
        "dc": dc(),
        "rt": rt(),
        "watchdog_ns": 0,
        "ring_capacity": 65536,
    }
    return _native.Plan(**{**base, **fields})


def _axis_defaults() -> dict[str, Any]:
    """An axis's fields as the configuration's defaults give them (``config/bus.py``
    ``AxisConfig``, the one place they live), mapped as ``master/axis.py`` maps them."""
    c = AxisConfig(name="j")
    return {
        "mode": c.mode,
        "position_scale": c.position_scale,
        "position_offset": c.position_offset,
        "velocity_scale": c.velocity_scale,
        "torque_scale": c.torque_scale,
        "position_min": c.position_limits[0],
        "position_max": c.position_limits[1],
        "velocity_max": c.velocity_limit,
        "torque_max": c.torque_limit,
        "deceleration": c.deceleration,
        "mode_change_velocity": c.mode_change_velocity,
        "restart": c.restart,
        "following_error_window": c.following_error_window,
        "on_stop": c.on_stop,
        "fault_reset": c.fault_reset,
        "fault_retries": c.fault_retries,
        "fault_backoff_ns": round(c.fault_backoff_ms * 1e6),
    }


AXIS_DEFAULTS = _axis_defaults()


def axis_plan(name: str, offsets: dict[str, int], **fields: Any) -> _native.AxisPlan:
    """An axis with its objects at ``offsets`` (role → image byte), the configuration's
    defaults and ``fields`` (``AxisPlan``'s own keywords)."""
    return _native.AxisPlan(
        name=name, map=_native.AxisMap(**offsets), **{**AXIS_DEFAULTS, **fields}
    )
