"""The node's ``diagnostics`` (diagnostic_msgs/DiagnosticArray): the master and every slave.

Master status: lifecycle state, cycles, lost/late frames, working-counter errors, watchdog trips,
panics, overruns, samples dropped (engine ring and ROS side), loop timing (wake-up latency,
execution time, period, round trip: p50/p99/max) and the largest DC sync error since the last
report. One status per slave group (``master/groups.py``): its cycle, frames, frames sent, lost
and late, working-counter errors and last working counter against the expected one. One status
per slave: its AL state and AL status code.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue

from ether_ros.ros import bridge

OK = DiagnosticStatus.OK
WARN = DiagnosticStatus.WARN
ERROR = DiagnosticStatus.ERROR
STALE = DiagnosticStatus.STALE

_COUNTERS = (
    "cycles",
    "lost_frames",
    "late_frames",
    "unmatched_frames",
    "wkc_errors",
    "watchdog_trips",
    "panics",
    "overruns",
    "send_errors",
    "samples_dropped",
    "acyclic_frames",
    "acyclic_timeouts",
)
_HISTOGRAMS = ("wake_latency", "exec", "period", "rtt")


def master_status(
    node_name: str,
    lifecycle: str,
    stats: Mapping[str, float],
    ros: Mapping[str, float],
    panic: bool,
    dc_error_ns: float,
) -> DiagnosticStatus:
    st = DiagnosticStatus()
    st.name = f"{node_name}: master"
    st.hardware_id = node_name
    values: list[tuple[str, str]] = [("lifecycle_state", lifecycle), ("panic", str(panic).lower())]
    for name in _COUNTERS:
        values.append((name, f"{int(bridge.stat(stats, name))}"))
    for h in _HISTOGRAMS:
        for q in ("p50", "p99", "max"):
            key = f"{h}.{q}"
            if key in stats or any(k.endswith("." + key) for k in stats):
                values.append((f"{h}_{q}_ns", f"{int(bridge.stat(stats, key))}"))
    values.append(("dc_sync_error_max_ns", f"{int(dc_error_ns)}"))
    for key, value in ros.items():
        values.append((f"ros_{key}", f"{value:g}"))
    st.values = [KeyValue(key=k, value=v) for k, v in values]
    lost = bridge.stat(stats, "lost_frames")
    if lifecycle != "active":
        st.level, st.message = OK, f"{lifecycle}: no cyclic exchange"
    elif panic:
        st.level, st.message = ERROR, "panic: safe outputs on the wire"
    elif ros.get("watchdog_cycles", 0) and ros.get("watchdog_active", 0):
        st.level, st.message = WARN, "command watchdog expired: safe outputs on the wire"
    elif lost:
        st.level, st.message = WARN, f"running, {int(lost)} frames lost"
    else:
        st.level, st.message = OK, "running"
    return st


def group_statuses(node_name: str, groups: Sequence[Any]) -> list[DiagnosticStatus]:
    """One status per slave group (``GroupStats``): WARN while its working counter is off."""
    out = []
    for g in groups:
        st = DiagnosticStatus()
        st.name = f"{node_name}: group {g.name}"
        st.hardware_id = node_name
        values = [
            ("cycle_us", f"{g.cycle_ns / 1000:g}"),
            ("frames", " ".join(str(k) for k in g.frames)),
            ("slaves", " ".join(g.slaves)),
            ("sent", str(g.sent)),
            ("lost_frames", str(g.lost)),
            ("late_frames", str(g.late)),
            ("wkc_errors", str(g.wkc_errors)),
            ("watchdog_trips", str(g.watchdog_trips)),
            ("working_counter", str(g.last_wkc)),
            ("expected_working_counter", str(g.expected_wkc)),
        ]
        st.values = [KeyValue(key=k, value=v) for k, v in values]
        if g.sent and not g.wkc_ok:
            st.level = WARN
            st.message = f"working counter {g.last_wkc}, expected {g.expected_wkc}"
        else:
            st.level, st.message = OK, f"every {g.cycle_ns / 1000:g} µs"
        out.append(st)
    return out


def slave_statuses(node_name: str, states: Sequence[Any]) -> list[DiagnosticStatus]:
    out = []
    for s in states:
        st = DiagnosticStatus()
        st.name = f"{node_name}: slave {s.name}"
        st.hardware_id = f"{s.position}"
        st.values = [
            KeyValue(key="position", value=str(s.position)),
            KeyValue(key="station", value=f"0x{int(s.station):04x}"),
            KeyValue(key="al_state", value=str(s.state)),
            KeyValue(key="al_error", value=str(bool(s.error)).lower()),
            KeyValue(key="al_status_code", value=f"0x{int(s.code):04x}"),
        ]
        if s.error:
            st.level = ERROR
            st.message = f"{s.state} with error 0x{int(s.code):04x}: {s.text}"
        elif str(s.state).upper() != "OP":
            st.level, st.message = WARN, str(s.state)
        else:
            st.level, st.message = OK, "OP"
        out.append(st)
    return out


def array(statuses: list[DiagnosticStatus], stamp: Any) -> DiagnosticArray:
    msg = DiagnosticArray()
    msg.header.stamp = stamp
    msg.status = statuses
    return msg


def values_of(status: DiagnosticStatus) -> dict[str, str]:
    return {kv.key: kv.value for kv in status.values}
