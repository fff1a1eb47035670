"""The node's ``diagnostics`` (diagnostic_msgs/DiagnosticArray): the master and every slave.

The levels say how things are *now*: they come from rates over a sliding window (``Window``,
``diagnostics_window_s``, 10 s by default) and from the current state, never from totals since
start, so one lost frame an hour ago does not keep the master in WARN. The totals are still
reported, as counters of their own.

Master status: lifecycle state, cycles, lost/late frames, working-counter errors, watchdog trips,
panics, overruns, samples dropped (engine ring and ROS side) since start; the same over the
window (``window_*``) with the loss rate; how old the oldest frame's inputs are
(``input_age_ms``, ``stale_frames``); loop timing (wake-up latency, execution time, period,
round trip: p50/p99/max) and the largest DC sync error since the last report. ERROR while
slaves are cut off (a cable broken on a branch: ``link lost behind slave 'coupler' port 2:
slaves … unreachable``, or a group's working counter short now), while a frame's inputs are
stale (no reply came back whole within ``STALE_S``) or when the loss rate over the window
reaches ``ERROR_RATE``; WARN from ``WARN_RATE`` (or an expired command watchdog). One status
per slave group (``master/groups.py``): its cycle, frames, frames sent, lost and late,
working-counter errors and last working counter against the expected one (ERROR while it is
short: slaves are not answering), with the same window. One status per slave: its AL state and
AL status code, and the supervisor's reason when the slave is lost (e.g. the broken cable that
cut it off). One per CiA 402 axis: its state, mode, error code with its text, following error
and clamp counts.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Mapping, Sequence
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue

from ether_ros._native.protocol import emergency_text
from ether_ros.config.types import format_number
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

#: Rates over the window (lost or late frames per frame sent; cycles with a working-counter
#: error, an overrun or a send error per cycle) from which the level is WARN, and ERROR.
WARN_RATE = 0.001
ERROR_RATE = 0.05
#: A frame whose last whole reply is older than this (or three of its periods, if longer) has
#: stale inputs: the bus, or that frame's slaves, are down now.
STALE_S = 0.1
#: The window's counters (master): totals whose increase over the window is reported.
WINDOW_COUNTERS = (
    "cycles",
    "frames_sent",
    "lost_frames",
    "late_frames",
    "wkc_errors",
    "overruns",
    "send_errors",
    "watchdog_trips",
)


class Window:
    """Increase of counter totals over the last ``seconds``: kept as the reports of that span,
    the oldest one the base. A total that went down (statistics reset, bus reopened) starts
    the window again from zero."""

    def __init__(self, seconds: float) -> None:
        self.seconds = float(seconds)
        self._reports: deque[tuple[float, dict[str, float]]] = deque()

    def update(self, now: float, totals: Mapping[str, float]) -> dict[str, float]:
        """The increase of each total over the window, and ``seconds`` it spans."""
        current = {k: float(v) for k, v in totals.items()}
        if self._reports and any(current[k] < self._reports[-1][1].get(k, 0.0) for k in current):
            self._reports.clear()
        if not self._reports:
            # Everything counted so far happened within this first span.
            self._reports.append((now, dict.fromkeys(current, 0.0)))
        self._reports.append((now, current))
        while len(self._reports) > 2 and now - self._reports[1][0] >= self.seconds:
            self._reports.popleft()
        t0, base = self._reports[0]
        out = {k: max(0.0, v - base.get(k, 0.0)) for k, v in current.items()}
        out["seconds"] = now - t0
        return out


class Windows:
    """The windows of one node: the master's and one per slave group (made on first use)."""

    def __init__(self, seconds: float) -> None:
        self.seconds = seconds
        self.master = Window(seconds)
        self.groups: dict[str, Window] = _GroupWindows(seconds)


class _GroupWindows(dict[str, Window]):
    def __init__(self, seconds: float) -> None:
        super().__init__()
        self.seconds = seconds

    def __missing__(self, name: str) -> Window:
        w = self[name] = Window(self.seconds)
        return w


def rate(count: float, total: float) -> float:
    return count / total if total > 0 else 0.0


def frame_ages(frames: Sequence[Mapping[str, Any]], cycle_ns: int, now_ns: int) -> list[float]:
    """How old each cyclic frame's inputs are (s; inf before its first whole reply)."""
    ages = []
    for f in frames:
        good = int(f.get("last_good_ns", 0))
        if not int(f.get("last_good_cycle", 0)) or good <= 0:
            ages.append(float("inf"))
        else:
            ages.append(max(0.0, (now_ns - good) / 1e9))
    return ages


def stale_frames(frames: Sequence[Mapping[str, Any]], cycle_ns: int, now_ns: int) -> list[int]:
    """The frames whose inputs are stale now (see ``STALE_S``)."""
    out = []
    for k, (f, age) in enumerate(zip(frames, frame_ages(frames, cycle_ns, now_ns), strict=True)):
        limit = max(STALE_S, 3 * int(f.get("every", 1)) * cycle_ns / 1e9)
        if age > limit:
            out.append(k)
    return out


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
    window: Mapping[str, float] | None = None,
    stale: Sequence[int] = (),
    input_age_s: float = 0.0,
    short_groups: Sequence[str] = (),
    frame_count: int = 0,
) -> DiagnosticStatus:
    """The master's status. ``window``: ``Window.update`` of the ``WINDOW_COUNTERS`` (None:
    judged on the totals, as over one window since start); ``stale``: frames whose inputs are
    stale now (of ``frame_count``); ``short_groups``: groups whose working counter is short
    now."""
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
    if window is None:
        window = {k: bridge.stat(stats, k) for k in WINDOW_COUNTERS}
        window["seconds"] = 0.0
    sent = window.get("frames_sent", 0.0) or window.get("cycles", 0.0)
    cycles = window.get("cycles", 0.0)
    lost_rate = rate(window.get("lost_frames", 0.0) + window.get("late_frames", 0.0), sent)
    cycle_rate = rate(
        window.get("wkc_errors", 0.0)
        + window.get("overruns", 0.0)
        + window.get("send_errors", 0.0),
        cycles,
    )
    values.append(("window_s", f"{window.get('seconds', 0.0):.1f}"))
    for name in WINDOW_COUNTERS:
        values.append((f"window_{name}", f"{int(window.get(name, 0.0))}"))
    values.append(("lost_rate", f"{lost_rate:.6f}"))
    values.append(("cycle_error_rate", f"{cycle_rate:.6f}"))
    age = "inf" if input_age_s == float("inf") else f"{input_age_s * 1000:.1f}"
    values.append(("input_age_ms", age))
    values.append(("stale_frames", " ".join(str(k) for k in stale)))
    for key, value in ros.items():
        values.append((f"ros_{key}", format_number(value)))
    for k, problem in enumerate(link_problems):
        values.append((f"link_problem_{k}", problem))
    st.values = [KeyValue(key=k, value=v) for k, v in values]
    in_window = int(window.get("lost_frames", 0.0))
    span = f"in the last {window.get('seconds', 0.0):.0f} s"
    if lifecycle != "active":
        st.level, st.message = OK, f"{lifecycle}: no cyclic exchange"
    elif panic:
        st.level, st.message = ERROR, "panic: safe outputs on the wire"
    elif link_problems:
        st.level, st.message = ERROR, "; ".join(link_problems)
    elif stale:
        what = "the bus is down" if len(stale) >= frame_count else "frames down"
        frames = ", ".join(map(str, stale))
        st.level = ERROR
        st.message = f"{what}: no whole reply to frame(s) {frames} for {age} ms"
    elif short_groups:
        st.level = ERROR
        st.message = f"slaves not answering in group(s) {', '.join(short_groups)}"
    elif lost_rate >= ERROR_RATE or cycle_rate >= ERROR_RATE:
        st.level = ERROR
        st.message = f"{lost_rate:.1%} of frames lost, {cycle_rate:.1%} of cycles in error {span}"
    elif ros.get("watchdog_cycles", 0) and ros.get("watchdog_active", 0):
        st.level, st.message = WARN, "command watchdog expired: safe outputs on the wire"
    elif lost_rate >= WARN_RATE or cycle_rate >= WARN_RATE:
        st.level = WARN
        st.message = f"{lost_rate:.2%} of frames lost, {cycle_rate:.2%} of cycles in error {span}"
    elif in_window:
        st.level, st.message = OK, f"running ({in_window} frame(s) lost {span})"
    else:
        st.level, st.message = OK, "running"
    return st


def group_statuses(
    node_name: str,
    groups: Sequence[Any],
    windows: Mapping[str, Window] | None = None,
    now: float = 0.0,
) -> list[DiagnosticStatus]:
    """One status per slave group (``GroupStats``): ERROR while its working counter is short
    (slaves not answering now) or its loss rate over the window reaches ``ERROR_RATE``, WARN
    from ``WARN_RATE``. ``windows`` (by group name, kept by the caller from report to report)
    give the rates; without them the totals are judged."""
    out = []
    for g in groups:
        st = DiagnosticStatus()
        st.name = f"{node_name}: group {g.name}"
        st.hardware_id = node_name
        totals = {"sent": g.sent, "lost": g.lost, "late": g.late, "wkc_errors": g.wkc_errors}
        win = windows[g.name].update(now, totals) if windows is not None else dict(totals)
        lost_rate = rate(win.get("lost", 0) + win.get("late", 0), win.get("sent", 0))
        wkc_rate = rate(win.get("wkc_errors", 0), win.get("sent", 0))
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
            ("window_s", f"{win.get('seconds', 0.0):.1f}"),
            ("window_lost_frames", str(int(win.get("lost", 0)))),
            ("window_wkc_errors", str(int(win.get("wkc_errors", 0)))),
            ("lost_rate", f"{lost_rate:.6f}"),
        ]
        st.values = [KeyValue(key=k, value=v) for k, v in values]
        if g.sent and not g.wkc_ok:
            st.level = ERROR
            st.message = f"working counter {g.last_wkc}, expected {g.expected_wkc}"
        elif lost_rate >= ERROR_RATE or wkc_rate >= ERROR_RATE:
            st.level, st.message = ERROR, f"{lost_rate:.1%} of frames lost, {wkc_rate:.1%} bad"
        elif lost_rate >= WARN_RATE or wkc_rate >= WARN_RATE:
            st.level, st.message = WARN, f"{lost_rate:.2%} of frames lost, {wkc_rate:.2%} bad"
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


# The flags of ``Axis.status()`` each axis status reports (true/false).
_AXIS_FLAGS = (
    "following_error_exceeded",
    "retries_exhausted",
    "halted",
    "restart_blocked",
    "enable_wanted",
    "mode_reached",
    "limit_active",
    "outside_limits",
)


def axis_statuses(
    node_name: str,
    axes: Sequence[tuple[str, str, Mapping[str, Any]]],
    panic: bool = False,
    causes: Mapping[str, str] | None = None,
) -> list[DiagnosticStatus]:
    """One status per axis (joint, commanded mode, ``Axis.status()``): ERROR in Fault (the
    message names the error code and its text), WARN when the axis is disabled by a stop and
    waits for an explicit enable (restart blocked, or the bus in panic), for a following error
    beyond the window, an automatic reset that gave up, or an axis at a limit; else OK with the
    state. ``blocked`` says why the axis would not follow a setpoint ("" when it would);
    ``causes``: what stopped an axis, by joint, as the node saw it (``stopped_by``)."""
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
        for flag in _AXIS_FLAGS:
            values.append((flag, str(bool(st.get(flag, False))).lower()))
        cause = (causes or {}).get(joint, "")
        blocked = bridge.axis_blocker(st, mode, panic, cause=cause)
        values.append(("blocked", blocked))
        values.append(("stopped_by", cause))
        d.values = [KeyValue(key=k, value=v) for k, v in values]
        state = str(st["state"])
        if state in ("fault", "fault_reaction_active"):
            d.level, d.message = ERROR, f"{state}: {describe(code or last)}"
        elif st.get("restart_blocked") or (panic and blocked) or (cause and blocked):
            # Disabled by a stop and waiting for an enable: not OK, the axis will not move.
            d.level, d.message = WARN, blocked
        elif st["retries_exhausted"]:
            d.level = ERROR
            d.message = f"{state}: automatic fault reset gave up (last {describe(last)})"
        elif st["following_error_exceeded"]:
            d.level = WARN
            d.message = f"{state}: following error {float(st['following_error']):.4g}"
        elif code:
            d.level, d.message = WARN, f"{state}: {describe(code)}"
        elif st.get("limit_active") or st.get("outside_limits"):
            where = "outside its limits" if st.get("outside_limits") else "at a limit"
            d.level, d.message = WARN, f"{state} ({mode}): {where}, the setpoint is clamped"
        else:
            d.level, d.message = OK, f"{state} ({mode})"
            if blocked:  # e.g. disabled on purpose: OK, but say that it will not move
                d.message += f": {blocked}"
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
