"""The node's ``diagnostics`` (diagnostic_msgs/DiagnosticArray): the master and every slave.

Master status: lifecycle state, cycles, lost/late frames, working-counter errors, watchdog trips,
panics, overruns, samples dropped (engine ring and ROS side), loop timing (wake-up latency,
execution time, period, round trip: p50/p99/max) and the largest DC sync error since the last
report; cables found broken on a branch (``link lost behind slave 'coupler' port 2: slaves …
unreachable``) make it WARN. One status per slave group (``master/groups.py``): its cycle,
frames, frames sent, lost and late, working-counter errors and last working counter against the
expected one. One status per slave: its AL state and AL status code, and the supervisor's reason
when the slave is lost (e.g. the broken cable that cut it off). One per CiA 402 axis: its state,
mode, error code with its text, following error and clamp counts.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue

from ether_ros._native.protocol import emergency_text
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


def describe(code: int) -> str:
    """``0x2310 continuous over-current``: an error code and its text (the protocol crate's)."""
    return f"0x{code & 0xFFFF:04X} {emergency_text(code)}"


def master_status(
    node_name: str,
    lifecycle: str,
    stats: Mapping[str, float],
    ros: Mapping[str, float],
    panic: bool,
    dc_error_ns: float,
    link_problems: Sequence[str] = (),
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
    for k, problem in enumerate(link_problems):
        values.append((f"link_problem_{k}", problem))
    st.values = [KeyValue(key=k, value=v) for k, v in values]
    lost = bridge.stat(stats, "lost_frames")
    if lifecycle != "active":
        st.level, st.message = OK, f"{lifecycle}: no cyclic exchange"
    elif panic:
        st.level, st.message = ERROR, "panic: safe outputs on the wire"
    elif ros.get("watchdog_cycles", 0) and ros.get("watchdog_active", 0):
        st.level, st.message = WARN, "command watchdog expired: safe outputs on the wire"
    elif link_problems:
        st.level, st.message = WARN, "; ".join(link_problems)
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
        problem = getattr(s, "problem", "")
        if problem:
            st.values.append(KeyValue(key="problem", value=problem))
        if problem and not s.error:
            st.level, st.message = ERROR, problem
        elif s.error:
            st.level = ERROR
            st.message = f"{s.state} with error 0x{int(s.code):04x}: {s.text}"
        elif str(s.state).upper() != "OP":
            st.level, st.message = WARN, str(s.state)
        else:
            st.level, st.message = OK, "OP"
        out.append(st)
    return out


_AXIS_NUMBERS = ("position", "velocity", "torque", "following_error", "target_position")
_AXIS_COUNTS = ("position_clamps", "velocity_clamps", "torque_clamps", "faults", "fault_resets")


def axis_statuses(
    node_name: str, axes: Sequence[tuple[str, str, Mapping[str, Any]]]
) -> list[DiagnosticStatus]:
    """One status per axis (joint, commanded mode, ``Axis.status()``): ERROR in Fault (the
    message names the error code and its text), WARN for a following error beyond the window
    or an automatic reset that gave up, else OK with the state."""
    out = []
    for joint, mode, st in axes:
        d = DiagnosticStatus()
        d.name = f"{node_name}: axis {joint}"
        d.hardware_id = joint
        code, last = int(st["error_code"]), int(st["last_fault_code"])
        values = [
            ("state", str(st["state"])),
            ("mode", mode),
            ("mode_display", str(st["mode_display"] or st["mode_display_code"])),
            ("statusword", f"0x{int(st['statusword']):04x}"),
            ("error_code", f"0x{code:04x}"),
            ("error_text", emergency_text(code)),
            ("last_fault_code", f"0x{last:04x}"),
            ("last_fault_text", emergency_text(last) if last else ""),
        ]
        values += [(k, f"{float(st[k]):.6g}") for k in _AXIS_NUMBERS]
        values += [(k, str(int(st[k]))) for k in _AXIS_COUNTS]
        for flag in ("following_error_exceeded", "retries_exhausted", "halted"):
            values.append((flag, str(bool(st[flag])).lower()))
        d.values = [KeyValue(key=k, value=v) for k, v in values]
        state = str(st["state"])
        if state in ("fault", "fault_reaction_active"):
            d.level, d.message = ERROR, f"{state}: {describe(code or last)}"
        elif st["retries_exhausted"]:
            d.level = ERROR
            d.message = f"{state}: automatic fault reset gave up (last {describe(last)})"
        elif st["following_error_exceeded"]:
            d.level = WARN
            d.message = f"{state}: following error {float(st['following_error']):.4g}"
        elif code:
            d.level, d.message = WARN, f"{state}: {describe(code)}"
        else:
            d.level, d.message = OK, f"{state} ({mode})"
            if last:  # a fault the drive recovered from stays visible
                d.message += f"; last fault {describe(last)} ({int(st['faults'])} so far)"
        out.append(d)
    return out


def array(statuses: list[DiagnosticStatus], stamp: Any) -> DiagnosticArray:
    msg = DiagnosticArray()
    msg.header.stamp = stamp
    msg.status = statuses
    return msg


def values_of(status: DiagnosticStatus) -> dict[str, str]:
    return {kv.key: kv.value for kv in status.values}
