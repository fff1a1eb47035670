"""The thesis's two experiments (chapter 6.2.1), on the simulator or on a real bus.

Trot (Table 6.1): every leg gets the trajectory, gains and filter of Table 6.1 with a = b = 0;
recording starts; ``b_ellipse100`` goes to 4 cm, then ``a_ellipse100`` to 5 cm (the firmware
moves linearly over ``Transition_time``), the robot trots for ``hold_s``, then a and b go back
to 0 in the reverse order, and the recording stops. The recording is then read back into the
steady-trot report of :mod:`ether_ros.tools.trot_metrics`: per leg and joint the share of time
at the PWM limit, peak PWM and speed, and the toe's distance from the desired path.

Frequency (Tables 6.3–6.5): the same standing configuration is run for one round per loop time,
from 400 µs down in steps of 50 µs; each round counts the frames lost (the thesis looked for
"skipped frames" in the kernel log) and a table is printed at the end.

Both drive the bus only through the ``Bus`` API and record with the :class:`Recorder` (a non-RT
thread), so they run unchanged against ``ether-ros sim`` on a veth pair or a real robot.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ether_ros.errors import EtherRosError
from ether_ros.laelaps import TROT_A_CM, TROT_B_CM, leg_outputs
from ether_ros.tools.bus_source import BusSampleSource, bus_info, split_samples
from ether_ros.tools.recording import FLAG_LATE, FLAG_LOST, Recorder, RecordingWriter
from ether_ros.tools.trot_metrics import LegReport


class ExperimentError(EtherRosError):
    """An experiment cannot run as asked: names the parameter or slave."""


def leg_of(slave_name: str) -> str:
    """FL/FR/HL/HR from a slave name such as ``front_left_leg`` or ``hind_right``."""
    name = slave_name.lower()
    front = any(w in name for w in ("front", "fore"))
    hind = any(w in name for w in ("hind", "rear", "back"))
    left, right = "left" in name, "right" in name
    if front == hind or left == right:
        raise ExperimentError(
            f"slave {slave_name!r}: cannot tell which leg it is; name it "
            "front_left/front_right/hind_left/hind_right (fore/rear also work)"
        )
    return ("F" if front else "H") + ("L" if left else "R")


@dataclass
class TrotPlan:
    transition_s: int = 3
    hold_s: float = 10.0
    settle_s: float = 1.0


@dataclass
class Phase:
    name: str
    start_s: float
    end_s: float


@dataclass
class TrotResult:
    legs: dict[str, str]
    phases: list[Phase]
    cycles_recorded: int
    lost_frames: int
    recording: Path | None
    # Times the command watchdog put the safe outputs on the wire during the run (this process
    # stalled longer than bus.watchdog_ms between two feeds).
    watchdog_trips: int = 0
    # The steady-trot report of every leg (from the recording; empty without one).
    report: list[LegReport] = field(default_factory=list)


def _wait(bus: Any, seconds: float, check: Callable[[], None] | None = None) -> None:
    """Sleep in short steps, feeding the command watchdog (the robot must not go to safe
    outputs because the experiment is merely waiting)."""
    end = time.monotonic() + seconds
    feed = getattr(bus, "feed_watchdog", None)
    while True:
        if feed is not None:
            feed()
        if check is not None:
            check()
        left = end - time.monotonic()
        if left <= 0:
            return
        time.sleep(min(0.02, left))


def trot(
    bus: Any, plan: TrotPlan, record: str | Path | None = None, log: Callable[[str], None] = print
) -> TrotResult:
    """Run the trot on an opened and started bus."""
    if not 0 <= plan.transition_s <= 127:
        raise ExperimentError(f"transition time must be 0..127 s (int8), got {plan.transition_s}")
    if plan.hold_s < 0:
        raise ExperimentError(f"hold time must not be negative, got {plan.hold_s}")
    legs: dict[str, str] = {}
    for s in bus.slaves:
        layout = s.layout
        if layout is None or not layout.has("a_ellipse100"):
            continue
        legs[s.name] = leg_of(s.name)
    if not legs:
        raise ExperimentError("no slave has the Laelaps II trajectory outputs (a_ellipse100)")
    # The whole command of every leg, sent at every step: a watchdog trip (a stall of this
    # process longer than bus.watchdog_ms) voids what was commanded before it (docs/security.md,
    # "A reset does not restart"), so a step never relies on what an earlier one wrote.
    ellipse = {"a_ellipse100": 0, "b_ellipse100": 0}

    def command() -> None:
        bus.write_slaves(
            {
                name: leg_outputs(
                    leg, ellipse["a_ellipse100"], ellipse["b_ellipse100"], plan.transition_s
                )
                for name, leg in legs.items()
            }
        )

    recorder = None
    writer = None
    if record is not None:
        writer = RecordingWriter(
            record,
            bus_info(bus),
            bus.config.joint_specs(),
            metadata={
                "experiment": "trot",
                "transition_s": str(plan.transition_s),
                "hold_s": str(plan.hold_s),
            },
        )
        recorder = Recorder(BusSampleSource(bus, bus.config.ros.decoded_decimation), writer)
        recorder.start()
    phases: list[Phase] = []
    t0 = time.monotonic()
    lost_before = _lost(bus)
    trips_before = _counter(bus, "watchdog_trips")

    def step(name: str, variable: str | None, value: int, seconds: float) -> None:
        start = time.monotonic() - t0
        if variable is not None:
            ellipse[variable] = value
            log(f"{start:6.1f} s  {name}")
        command()
        _wait(bus, seconds)
        phases.append(Phase(name, start, time.monotonic() - t0))

    try:
        step("stand", None, 0, plan.settle_s)
        step(f"b -> {TROT_B_CM} cm", "b_ellipse100", TROT_B_CM, plan.transition_s)
        step(f"a -> {TROT_A_CM} cm", "a_ellipse100", TROT_A_CM, plan.transition_s)
        step("trot", None, 0, plan.hold_s)
        step("a -> 0", "a_ellipse100", 0, plan.transition_s)
        step("b -> 0", "b_ellipse100", 0, plan.transition_s)
        step("stand", None, 0, plan.settle_s)
    finally:
        if recorder is not None:
            recorder.stop()
    report: list[LegReport] = []
    if record is not None:
        from ether_ros.tools.recording import read_recording
        from ether_ros.tools.trot_metrics import trot_report

        report = trot_report(read_recording(record))
    return TrotResult(
        legs,
        phases,
        writer.cycles if writer else 0,
        _lost(bus) - lost_before,
        Path(record) if record is not None else None,
        _counter(bus, "watchdog_trips") - trips_before,
        report,
    )


def _lost(bus: Any) -> int:
    return _counter(bus, "lost_frames")


def _counter(bus: Any, name: str) -> int:
    from ether_ros.tools.live import stat

    return int(stat(bus.stats(), name))


# ---- frequency ---------------------------------------------------------------------------


@dataclass
class Round:
    cycle_us: int
    seconds: float
    cycles: int = 0
    lost: int = 0
    late: int = 0
    rtt_median_us: float | None = None
    wake_latency_max_us: float | None = None
    error: str = ""
    recording: Path | None = None

    @property
    def frequency_khz(self) -> float:
        return 1000.0 / self.cycle_us


@dataclass
class RoundCounter:
    """Counts one round's cycles from the samples, as the Recorder's source would."""

    cycles: int = 0
    lost: int = 0
    late: int = 0
    rtt: list[np.ndarray] = field(default_factory=list)
    latency_max_ns: int = 0

    def add(self, records: Any) -> None:
        n = len(records)
        if not n:
            return
        names = records.dtype.names or ()
        self.cycles += n
        flags = records["flags"] if "flags" in names else np.zeros(n, dtype=np.uint16)
        self.lost += int(np.count_nonzero(flags & FLAG_LOST))
        self.late += int(np.count_nonzero(flags & FLAG_LATE))
        if "rtt_ns" in names:
            rtt = np.asarray(records["rtt_ns"])
            self.rtt.append(rtt[rtt > 0])
        if "wake_latency_ns" in names:
            self.latency_max_ns = max(self.latency_max_ns, int(np.max(records["wake_latency_ns"])))


def loop_times(from_us: int, step_us: int, to_us: int) -> list[int]:
    if step_us <= 0:
        raise ExperimentError(f"--step-us must be positive, got {step_us}")
    if from_us < to_us:
        raise ExperimentError(
            f"--from-us ({from_us}) must not be below --to-us ({to_us}): the "
            "experiment goes from the slow loop down to the fast one"
        )
    if to_us < 20:
        raise ExperimentError(f"--to-us must be at least 20 µs, got {to_us}")
    return list(range(from_us, to_us - 1, -step_us))


class _CountingSource:
    """Wraps the bus sample source so the round counter sees every record it writes."""

    def __init__(self, source: BusSampleSource, counter: RoundCounter) -> None:
        self.source = source
        self.counter = counter

    def cycles(self) -> list[Any]:
        data = self.source.cycles()
        for d in data:
            t = d.timing
            self.counter.cycles += 1
            self.counter.lost += bool(t.flags & FLAG_LOST)
            self.counter.late += bool(t.flags & FLAG_LATE)
            if t.rtt_ns:
                self.counter.rtt.append(np.array([t.rtt_ns]))
            self.counter.latency_max_ns = max(self.counter.latency_max_ns, t.wake_latency_ns)
        return data

    def stats(self) -> dict[str, Any]:
        return self.source.stats()


def frequency(
    open_bus: Callable[[int], Any],
    cycles_us: list[int],
    round_s: float,
    record: str | Path | None = None,
    log: Callable[[str], None] = print,
) -> list[Round]:
    """One round per loop time. ``open_bus(cycle_us)`` returns an opened (not started) bus."""
    if round_s <= 0:
        raise ExperimentError(f"--round-seconds must be positive, got {round_s}")
    rounds: list[Round] = []
    for cycle_us in cycles_us:
        result = Round(cycle_us, round_s)
        counter = RoundCounter()
        log(f"round {cycle_us} µs ({1000.0 / cycle_us:.3f} kHz) for {round_s:g} s")
        bus = open_bus(cycle_us)
        try:
            bus.start()
        except EtherRosError as exc:
            # The thesis's slaves refused OP at 220 µs: a finding, not a failure of the tool.
            result.error = f"did not reach OP: {exc}"
            bus.close()
            rounds.append(result)
            log(f"  {result.error}")
            continue
        try:
            for s in bus.slaves:  # standing, as in the thesis (a = b = 0)
                if s.layout is not None and s.layout.has("a_ellipse100"):
                    bus.write_many(s.name, leg_outputs(leg_of(s.name), 0, 0, 0))
            bus.samples()  # start counting from here: bring-up cycles are not the round's
            if record is not None:
                path = _round_path(Path(record), cycle_us)
                writer = RecordingWriter(
                    path,
                    bus_info(bus),
                    bus.config.joint_specs(),
                    metadata={"experiment": "frequency", "cycle_us": str(cycle_us)},
                )
                source = _CountingSource(
                    BusSampleSource(bus, bus.config.ros.decoded_decimation), counter
                )
                with Recorder(source, writer):
                    _wait(bus, round_s)
                result.recording = path
            else:
                end = time.monotonic() + round_s
                while time.monotonic() < end:
                    _wait(bus, min(0.1, end - time.monotonic()))
                    counter.add(split_samples(bus.samples())[0])
                counter.add(split_samples(bus.samples())[0])
        finally:
            bus.close()
        result.cycles, result.lost, result.late = counter.cycles, counter.lost, counter.late
        rtt = np.concatenate(counter.rtt) if counter.rtt else np.empty(0)
        result.rtt_median_us = float(np.median(rtt)) / 1000 if rtt.size else None
        result.wake_latency_max_us = counter.latency_max_ns / 1000 if counter.cycles else None
        log(f"  {result.cycles} cycles, {result.lost} lost, {result.late} late")
        rounds.append(result)
    return rounds


def _round_path(base: Path, cycle_us: int) -> Path:
    suffix = base.suffix or ".mcap"
    return base.with_name(f"{base.stem}_{cycle_us}us{suffix}")


def frequency_table(rounds: list[Round]) -> str:
    header = (
        f"{'loop time (µs)':>14}  {'frequency (kHz)':>15}  {'cycles':>8}  {'lost':>6}  "
        f"{'late':>6}  {'RTT median (µs)':>15}  {'max wake-up latency (µs)':>24}"
    )
    lines = [header, "-" * len(header)]
    for r in rounds:
        if r.error:
            lines.append(f"{r.cycle_us:>14}  {r.frequency_khz:>15.3f}  {r.error}")
            continue
        rtt = f"{r.rtt_median_us:.1f}" if r.rtt_median_us is not None else "-"
        lat = f"{r.wake_latency_max_us:.1f}" if r.wake_latency_max_us is not None else "-"
        lines.append(
            f"{r.cycle_us:>14}  {r.frequency_khz:>15.3f}  {r.cycles:>8}  {r.lost:>6}  "
            f"{r.late:>6}  {rtt:>15}  {lat:>24}"
        )
    clean = [r for r in rounds if not r.error and r.cycles and r.lost == 0]
    if clean:
        best = min(clean, key=lambda r: r.cycle_us)
        lines.append(
            f"shortest loop time without lost frames: {best.cycle_us} µs "
            f"({best.frequency_khz:.3f} kHz)"
        )
    else:
        lines.append("no round ran without lost frames")
    return "\n".join(lines)
