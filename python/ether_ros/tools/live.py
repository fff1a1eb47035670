"""``ether-ros top``: a live view of the bus (slaves and states, loop timing, lost frames, DC).

The screen (:class:`TopApp`, textual) draws :class:`LiveSnapshot` objects; where they come from
is a :class:`LiveSource`: a standalone bus opened by this process (:class:`BusLiveSource`) or
the running ROS 2 node's diagnostics (:class:`ether_ros.ros.top_source.DiagnosticsLiveSource`,
beside the node it reads: the tools import no ROS module). Tests feed the screen a source of
their own.

Ctrl-P and F1 panic, as in the console: the source sends it (the standalone bus at once, the
node through a panic line of its own, :class:`KeyLine` here).
"""

from __future__ import annotations

import asyncio
import contextlib
import math
import os
import signal
import threading
from collections import deque
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any, ClassVar, Protocol

import numpy as np
from textual import events
from textual.app import App, ComposeResult
from textual.binding import Binding
from textual.containers import Horizontal, Vertical
from textual.driver import Driver
from textual.widgets import DataTable, Footer, Header, Static

HISTOGRAM_BINS = 12
PANIC_KEYS = ("ctrl+p", "f1")


@dataclass
class SlaveRow:
    position: int
    name: str
    state: str  # INIT, PREOP, SAFEOP, OP, BOOT (+ " ERR" when the error flag is set)
    detail: str = ""  # AL status code text, device name, ...


@dataclass
class AxisRow:
    """A CiA 402 axis: its joint, CiA 402 state, mode, position (SI), error and extras."""

    joint: str
    state: str
    mode: str
    position: float
    error: str = ""  # "0x2310 continuous over-current" (the last fault, when recovered)
    # The axis's ``extras:`` in SI (``Axis.extras`` / the node's ``joint_extras``), in
    # configuration order; empty when it has none.
    extras: dict[str, float] = field(default_factory=dict)
    # Why it would not follow a setpoint (restart blocked, disabled, in fault, panic), or that
    # it is at a limit: "" when neither (``axis_note``).
    note: str = ""


def axis_note(blocked: str, limit_active: bool, outside_limits: bool) -> str:
    """What ``top`` says after an axis's error: why it cannot move, else whether a limit
    clamps its setpoint."""
    if blocked:
        return f"NOT MOVING: {blocked}"
    if outside_limits:
        return "outside its limits"
    if limit_active:
        return "at a limit"
    return ""


@dataclass
class GroupRow:
    """One slave group: its cycle, frames and working counter (``master/groups.py``)."""

    name: str
    cycle_us: float
    lost_frames: int
    late_frames: int
    wkc_errors: int
    wkc: int
    expected_wkc: int

    def text(self) -> str:
        return (
            f"group {self.name}: every {self.cycle_us:g} µs   lost {self.lost_frames}   "
            f"late {self.late_frames}   WKC errors {self.wkc_errors}   "
            f"WKC {self.wkc}/{self.expected_wkc}"
        )


@dataclass
class LiveSnapshot:
    bus: str = ""
    cycle_us: int = 0
    cycles: int = 0
    lost_frames: int = 0
    late_frames: int = 0
    wkc_errors: int = 0
    dc_sync_error_ns: float | None = None
    panic: bool = False
    slaves: list[SlaveRow] = field(default_factory=list)
    axes: list[AxisRow] = field(default_factory=list)
    groups: list[GroupRow] = field(default_factory=list)
    # Recent per-cycle values, µs (what the histograms are made of).
    wake_latency_us: Sequence[float] = ()
    exec_us: Sequence[float] = ()
    period_us: Sequence[float] = ()
    rtt_us: Sequence[float] = ()
    # Timing as (p50, p99, max) µs by name, when only quantiles are known (the ROS node).
    quantiles_us: dict[str, tuple[float, float, float]] = field(default_factory=dict)
    source: str = ""
    error: str = ""  # the source cannot deliver (node gone, bus closed): shown, not raised
    stale: str = ""  # the data is older than two report periods: why, shown above everything


class LiveSource(Protocol):
    def poll(self) -> LiveSnapshot: ...

    def panic(self, report: Callable[[str], None]) -> None:
        """Send a panic now (never block); ``report`` gets the outcome, from any thread."""
        ...

    def close(self) -> None: ...


class KeyLine(Protocol):
    """A source's own panic line with a native key reader (the node's: ``ros/panic_line.py``):
    ``run_top`` puts it between the terminal and textual."""

    def watch_terminal(self, terminal: int) -> int | None: ...

    def stop_watching(self) -> None: ...


# ---- text rendering (kept separate from textual so it can be read and tested plainly) ---------

_BLOCKS = " ▁▂▃▄▅▆▇█"


def histogram_text(label: str, values: Sequence[float], bins: int = HISTOGRAM_BINS) -> str:
    """One histogram as text: a row of bars, its range, median and maximum (µs)."""
    data = np.asarray(values, dtype=float)
    data = data[np.isfinite(data)]
    if data.size == 0:
        return f"{label:<16} no data"
    lo, hi = float(data.min()), float(data.max())
    if hi - lo < 1e-9:
        hi = lo + 1.0
    counts, _ = np.histogram(data, bins=bins, range=(lo, hi))
    peak = counts.max() or 1
    # Log scale: the tail (the few late cycles) is what matters, and it would vanish linearly.
    bars = "".join(
        _BLOCKS[0 if c == 0 else max(1, round(math.log1p(c) / math.log1p(peak) * 8))]
        for c in counts
    )
    return (
        f"{label:<16} {lo:8.1f} |{bars}| {hi:8.1f} µs   median {np.median(data):7.1f}"
        f"  max {data.max():7.1f}"
    )


def stats_text(s: LiveSnapshot) -> str:
    dc = "n/a" if s.dc_sync_error_ns is None else f"{s.dc_sync_error_ns:.0f} ns"
    freq = f"{1e6 / s.cycle_us:.0f} Hz" if s.cycle_us else "?"
    lines = [f"STALE: {s.stale}"] if s.stale else []
    lines += [
        f"bus {s.bus or '?'}   cycle {s.cycle_us} µs ({freq})   cycles {s.cycles}"
        + ("   PANIC" if s.panic else ""),
        f"lost frames {s.lost_frames}   late frames {s.late_frames}   "
        f"working counter errors {s.wkc_errors}   DC sync error {dc}",
    ]
    lines.extend(g.text() for g in s.groups)
    if s.error:
        lines.append(f"source: {s.error}")
    return "\n".join(lines)


def axes_text(s: LiveSnapshot) -> str:
    """The CiA 402 axes, one line each (empty for a bus without axes)."""
    if not s.axes:
        return ""
    lines = [f"{'joint':<16} {'state':<24} {'mode':<5} {'position':>10}  error"]
    for a in s.axes:
        error = "  ".join(x for x in (a.error, a.note) if x)
        lines.append(f"{a.joint:<16} {a.state:<24} {a.mode:<5} {a.position:10.4f}  {error}")
        if a.extras:
            lines.append(f"{'':<16} {extras_text(a.extras)}")
    return "\n".join(lines)


def extras_text(extras: dict[str, float]) -> str:
    """An axis's extras on one line, ``name=value`` in SI: whole numbers (digital inputs and
    outputs, counters) exactly, the rest to four significant digits."""

    def shown(value: float) -> str:
        if math.isfinite(value) and value == int(value) and abs(value) < 2**53:
            return str(int(value))
        return f"{value:.4g}"

    return "  ".join(f"{name}={shown(value)}" for name, value in extras.items())


def timing_text(s: LiveSnapshot) -> str:
    panels = (
        ("wake_latency", "wake-up latency", s.wake_latency_us),
        ("exec", "execution", s.exec_us),
        ("period", "period", s.period_us),
        ("rtt", "round trip", s.rtt_us),
    )
    lines = []
    for key, label, values in panels:
        if not values and key in s.quantiles_us:
            p50, p99, top = s.quantiles_us[key]
            lines.append(f"{label:<16} p50 {p50:8.1f}  p99 {p99:8.1f}  max {top:8.1f} µs")
        else:
            lines.append(histogram_text(label, values))
    return "\n".join(lines)


# ---- the screen ---------------------------------------------------------------------------


class TopApp(App[None]):
    """Slaves, statistics and timing histograms, refreshed every ``interval`` seconds.

    Keys: Ctrl-P or F1 panic (the command palette is off: Ctrl-P is the panic key), q quits.
    On a terminal the panic keys are acted on in the thread that reads the terminal, before the
    event loop sees them (so a busy loop cannot delay them); the bindings serve the rest (a test's
    simulated keys). SIGTERM and SIGHUP end it cleanly."""

    TITLE = "ether-ros top"
    ENABLE_COMMAND_PALETTE = False
    BINDINGS: ClassVar = [
        Binding("ctrl+p", "panic", "PANIC", priority=True),
        Binding("f1", "panic", "PANIC", show=False, priority=True),
        Binding("q", "quit", "quit"),
    ]
    CSS = """
    #stats { height: auto; padding: 0 1; }
    #message { height: auto; padding: 0 1; color: $error; }
    #slaves { height: auto; max-height: 50%; }
    #axes { height: auto; padding: 0 1; }
    #timing { height: auto; padding: 0 1; }
    """

    def __init__(self, source: LiveSource, interval: float = 0.5) -> None:
        super().__init__()
        self.source = source
        self.interval = interval
        self.snapshot = LiveSnapshot()
        self.messages: list[str] = []  # what the panic key reported, newest last
        self._app_thread = threading.get_ident()
        self._loop: asyncio.AbstractEventLoop | None = None

    def get_driver_class(self) -> type[Driver]:
        base: Any = super().get_driver_class()
        app = self

        class PanicFirstDriver(base):
            def process_message(self, message: Any) -> None:
                # The terminal's reading thread: a panic key goes out from here.
                if isinstance(message, events.Key) and message.key in PANIC_KEYS:
                    app.action_panic()
                    return
                super().process_message(message)

        return PanicFirstDriver

    def compose(self) -> ComposeResult:
        yield Header()
        with Vertical():
            yield Static("", id="stats")
            yield Static("", id="message")
            with Horizontal():
                yield DataTable(id="slaves", cursor_type="row", zebra_stripes=True)
            yield Static("", id="axes")
            yield Static("", id="timing")
        yield Footer()

    def on_mount(self) -> None:
        self._app_thread = threading.get_ident()
        self._loop = loop = asyncio.get_running_loop()
        for sig in (signal.SIGTERM, signal.SIGHUP):
            # Not in the main thread (the tests' run_test): no signals to take.
            with contextlib.suppress(ValueError, RuntimeError):
                loop.add_signal_handler(sig, self.exit)
        table = self.query_one("#slaves", DataTable)
        table.add_columns("pos", "slave", "state", "detail")
        self.refresh_view()
        self.set_interval(self.interval, self.refresh_view)

    def action_panic(self) -> None:
        """Send the panic (from the terminal's reading thread, or a binding)."""
        self.source.panic(self._report)

    def _report(self, message: str) -> None:
        """From any thread, never waiting: show ``message`` on the screen."""
        if threading.get_ident() == self._app_thread:
            self.show_message(message)
        elif self._loop is not None:
            with contextlib.suppress(RuntimeError):  # the app is ending
                self._loop.call_soon_threadsafe(self.show_message, message)

    def show_message(self, message: str) -> None:
        self.messages.append(message)
        del self.messages[:-3]
        self.query_one("#message", Static).update("\n".join(self.messages))

    def refresh_view(self) -> None:
        try:
            snapshot = self.source.poll()
        except Exception as exc:  # the view must survive a source that went away
            snapshot = LiveSnapshot(error=str(exc) or type(exc).__name__)
        self.snapshot = snapshot
        self.sub_title = snapshot.source
        self.query_one("#stats", Static).update(stats_text(snapshot))
        self.query_one("#axes", Static).update(axes_text(snapshot))
        self.query_one("#timing", Static).update(timing_text(snapshot))
        table = self.query_one("#slaves", DataTable)
        table.clear()
        for row in snapshot.slaves:
            table.add_row(str(row.position), row.name, row.state, row.detail, key=str(row.position))

    def on_unmount(self) -> None:
        self.source.close()


def run_top(app: TopApp, terminal: int = 0) -> None:
    """Run ``app`` on this terminal. For the node, the native key reader
    (:meth:`KeyLine.watch_terminal`) sits between the terminal and textual: it sends the panic
    the moment a panic key arrives, whatever the screen is doing, and passes every byte on to
    textual through a pipe that takes the terminal's place as stdin (fd 0)."""
    from prompt_toolkit.input.vt100 import raw_mode

    line: KeyLine | None = getattr(app.source, "panic_line", None)
    if line is None or not os.isatty(terminal):
        app.run()
        return
    tty = os.dup(terminal)
    try:
        with raw_mode(tty):  # textual's own settings fail on the pipe: the same ones here
            keys = line.watch_terminal(tty)
            if keys is None:
                app.run()
                return
            os.dup2(keys, terminal)
            try:
                app.run()
            finally:
                os.dup2(tty, terminal)
                line.stop_watching()
                os.close(keys)
    finally:
        os.close(tty)


# ---- sources ------------------------------------------------------------------------------


def _get(obj: Any, name: str, default: Any = 0) -> Any:
    if isinstance(obj, dict):
        return obj.get(name, default)
    return getattr(obj, name, default)


def _flatten(d: Any, prefix: str = "") -> dict[str, Any]:
    flat: dict[str, Any] = {}
    for key, value in dict(d).items():
        if isinstance(value, dict):
            flat.update(_flatten(value, f"{prefix}{key}."))
        else:
            flat[f"{prefix}{key}"] = value
    return flat


def stat(stats: Any, name: str, default: float = 0.0) -> float:
    """A statistic by its last name part, wherever the engine nests it
    (``counters.lost_frames``)."""
    flat = _flatten(stats)
    if name in flat:
        return float(flat[name])
    for key, value in flat.items():
        if key.endswith("." + name):
            return float(value)
    return default


class BusLiveSource:
    """A bus this process opened (``Bus``): its states, statistics and samples.

    Samples are drained at every poll; the last ``window`` cycles feed the histograms and the
    DC sync error (largest |difference| in the window).
    """

    def __init__(self, bus: Any, window: int = 5000, owns_bus: bool = True) -> None:
        self.bus = bus
        self.owns_bus = owns_bus
        self.window = window
        self._columns: dict[str, deque[float]] = {
            k: deque(maxlen=window)
            for k in ("wake_latency_ns", "exec_ns", "period_ns", "rtt_ns", "dc_diff_ns")
        }

    def _take_samples(self) -> None:
        from ether_ros.tools.bus_source import split_samples

        records, _images = split_samples(self.bus.samples())
        if not len(records):
            return
        names = records.dtype.names or ()
        for key, column in self._columns.items():
            if key not in names:
                continue
            values = np.asarray(records[key], dtype=float)
            if key == "rtt_ns":
                values = values[values > 0]  # 0: no reply processed in that cycle
            if key == "period_ns":
                values = values[values > 0]  # 0: the first cycle
            column.extend((values / 1000.0).tolist() if key != "dc_diff_ns" else values)

    def poll(self) -> LiveSnapshot:
        self._take_samples()
        stats = self.bus.stats()
        cfg = self.bus.config.bus
        slaves = []
        for st in self.bus.states():
            state = str(_get(st, "state", "?")) + (" ERR" if _get(st, "error", False) else "")
            code = int(_get(st, "code", 0))
            detail = f"0x{code:04x} {_get(st, 'text', '')}" if _get(st, "error", False) else ""
            slaves.append(
                SlaveRow(int(_get(st, "position")), str(_get(st, "name", "")), state, detail)
            )
        dc = self._columns["dc_diff_ns"]
        return LiveSnapshot(
            axes=[
                axis_row(a.name, a.mode, a.status(), a.extras if a.spec.extras else {})
                for a in getattr(self.bus, "axes", list)()
            ],
            bus=str(cfg.name),
            cycle_us=int(cfg.cycle_us),
            cycles=int(stat(stats, "cycles")),
            lost_frames=int(stat(stats, "lost_frames")),
            late_frames=int(stat(stats, "late_frames")),
            wkc_errors=int(stat(stats, "wkc_errors")),
            dc_sync_error_ns=max((abs(x) for x in dc), default=None),
            panic=bool(stat(stats, "panic")),
            slaves=slaves,
            groups=[
                GroupRow(
                    g.name,
                    g.cycle_ns / 1000,
                    g.lost,
                    g.late,
                    g.wkc_errors,
                    g.last_wkc,
                    g.expected_wkc,
                )
                for g in self.bus.group_stats(stats)
            ],
            wake_latency_us=list(self._columns["wake_latency_ns"]),
            exec_us=list(self._columns["exec_ns"]),
            period_us=list(self._columns["period_ns"]),
            rtt_us=list(self._columns["rtt_ns"]),
            source=f"standalone bus on {cfg.interface}",
        )

    def panic(self, report: Callable[[str], None]) -> None:
        self.bus.panic()
        report(
            "PANIC: safe outputs on the wire (the bus top opened); they stay until top ends "
            "and closes the bus"
        )

    def close(self) -> None:
        if self.owns_bus:
            self.bus.close()


def axis_row(
    joint: str, mode: str, status: dict[str, Any], extras: dict[str, float] | None = None
) -> AxisRow:
    """A row from an ``Axis.status()`` and ``Axis.extras`` (a standalone bus)."""
    from ether_ros._native.protocol import emergency_text
    from ether_ros.master.axis import axis_blocker

    code = int(status["error_code"]) or int(status["last_fault_code"])
    text = f"0x{code:04X} {emergency_text(code)}" if code else ""
    note = axis_note(
        axis_blocker(status, mode),
        bool(status.get("limit_active")),
        bool(status.get("outside_limits")),
    )
    return AxisRow(
        joint,
        str(status["state"]),
        mode,
        float(status["position"]),
        text,
        dict(extras or {}),
        note,
    )


def snapshot_from_diagnostics(
    master: dict[str, str],
    slaves: dict[str, tuple[str, dict[str, str]]],
    bus: str = "",
    axes: dict[str, dict[str, str]] | None = None,
    groups: dict[str, dict[str, str]] | None = None,
    extras: dict[str, dict[str, float]] | None = None,
) -> LiveSnapshot:
    """A snapshot from the node's diagnostics (``ether_ros.ros.diagnostics``).

    ``master``: the key/values of the "<node>: master" status (cycles, lost_frames,
    late_frames, wkc_errors, panic, <h>_p50_ns/_p99_ns/_max_ns for the loop timing,
    dc_sync_error_max_ns). ``slaves``: slave name -> (message, key/values of its status:
    position, al_state, al_error, al_status_code). ``axes``: joint -> key/values of its
    "axis" status (state, mode, position, error_code/_text, last_fault_code/_text, blocked,
    limit_active, outside_limits).
    ``groups``: group name -> key/values of its "<node>: group <name>" status. The node sends
    quantiles, not every cycle, so the timing is shown as p50/p99/max.
    """

    def num(key: str, default: float = 0.0) -> float:
        try:
            return float(master.get(key, default))
        except ValueError:
            return default

    rows = []
    for name, (message, kv) in slaves.items():
        error = kv.get("al_error", "false") == "true"
        state = kv.get("al_state", "?") + (" ERR" if error else "")
        try:
            position = int(kv.get("position", "0"))
        except ValueError:
            position = 0
        rows.append(SlaveRow(position, name, state, message if error else ""))
    rows.sort(key=lambda r: r.position)
    quantiles = {}
    for h in ("wake_latency", "exec", "period", "rtt"):
        if f"{h}_p50_ns" in master:
            quantiles[h] = (
                num(f"{h}_p50_ns") / 1000,
                num(f"{h}_p99_ns") / 1000,
                num(f"{h}_max_ns") / 1000,
            )
    dc = master.get("dc_sync_error_max_ns")
    axis_rows = []
    for joint, kv in (axes or {}).items():
        code, text = kv.get("error_code", "0x0000"), kv.get("error_text", "")
        if code == "0x0000" and kv.get("last_fault_code", "0x0000") != "0x0000":
            code, text = kv["last_fault_code"], kv.get("last_fault_text", "")
        try:
            joint_position = float(kv.get("position", "nan"))
        except ValueError:
            joint_position = math.nan
        shown = f"{code} {text}" if code != "0x0000" else ""
        axis_rows.append(
            AxisRow(
                joint,
                kv.get("state", "?"),
                kv.get("mode", "?"),
                joint_position,
                shown,
                dict((extras or {}).get(joint, {})),
                axis_note(
                    kv.get("blocked", ""),
                    kv.get("limit_active") == "true",
                    kv.get("outside_limits") == "true",
                ),
            )
        )
    return LiveSnapshot(
        axes=axis_rows,
        bus=bus,
        cycles=int(num("cycles")),
        lost_frames=int(num("lost_frames")),
        late_frames=int(num("late_frames")),
        wkc_errors=int(num("wkc_errors")),
        dc_sync_error_ns=None if dc in (None, "") else num("dc_sync_error_max_ns"),
        panic=master.get("panic", "false") == "true",
        slaves=rows,
        groups=[_group_row(name, kv) for name, kv in (groups or {}).items()],
        quantiles_us=quantiles,
        source=f"ROS 2 diagnostics ({master.get('lifecycle_state', '?')})",
    )


def _group_row(name: str, kv: dict[str, str]) -> GroupRow:
    def num(key: str) -> float:
        try:
            return float(kv.get(key, 0))
        except ValueError:
            return 0.0

    return GroupRow(
        name,
        num("cycle_us"),
        int(num("lost_frames")),
        int(num("late_frames")),
        int(num("wkc_errors")),
        int(num("working_counter")),
        int(num("expected_working_counter")),
    )


class StaticSource:
    """A fixed sequence of snapshots (the last one repeats); for demos and tests."""

    def __init__(self, snapshots: Iterable[LiveSnapshot]) -> None:
        self._snapshots = list(snapshots)
        self._i = 0
        self.closed = False
        self.panics = 0

    def poll(self) -> LiveSnapshot:
        snap = self._snapshots[min(self._i, len(self._snapshots) - 1)]
        self._i += 1
        return snap

    def panic(self, report: Callable[[str], None]) -> None:
        self.panics += 1
        report(f"PANIC (static source, {self.panics})")

    def close(self) -> None:
        self.closed = True
