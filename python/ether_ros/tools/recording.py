"""Recordings of a running bus: MCAP files with ROS 2 message schemas.

A recording holds, on these topics:

- ``/ether_ros/layout`` (BusLayout, once): the slaves and the names of their variables;
- ``/ether_ros/timing`` (CycleTimingBatch): every cycle's wake-up latency, execution time,
  period, round trip, working counter and flags, in batches;
- ``/ether_ros/<slave>/inputs`` and ``.../outputs`` (SlaveValues): decoded values, every
  ``decoded_decimation`` cycles;
- ``/ether_ros/pdo_raw`` (PdoRaw): the raw images, every ``raw_decimation`` cycles (0: never);
- ``/joint_states`` (sensor_msgs/JointState) when joints are configured;
- ``/diagnostics`` (diagnostic_msgs/DiagnosticArray): the bus statistics, about once a second.

The file opens in Foxglove or with ``ros2 bag`` (MCAP storage). :class:`Recorder` feeds a
:class:`RecordingWriter` from ``Bus.samples()`` in its own (non real-time) thread; the RT thread
only fills the sample ring and never waits for the recorder. :func:`read_recording` loads a file
back into numpy arrays for the plots and experiments.
"""

from __future__ import annotations

import struct
import threading
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any, Protocol

import numpy as np

from ether_ros.config.bus import JointSpec
from ether_ros.errors import EtherRosError
from ether_ros.tools.msgdefs import DEFINITIONS

FORMAT_NAME = "ether_ros recording"
FORMAT_VERSION = "1"
METADATA_NAME = "ether_ros"

TOPIC_LAYOUT = "/ether_ros/layout"
TOPIC_TIMING = "/ether_ros/timing"
TOPIC_RAW = "/ether_ros/pdo_raw"
TOPIC_JOINTS = "/joint_states"
TOPIC_DIAGNOSTICS = "/diagnostics"
TIMING_BATCH = 250  # cycles per CycleTimingBatch message (0.1 s at 2.5 kHz)

# Sample flags, as the engine sets them (crates/engine/src/handover.rs `flags`).
FLAG_LOST = 1 << 0
FLAG_LATE = 1 << 1
FLAG_WKC_ERROR = 1 << 2


def inputs_topic(slave: str) -> str:
    return f"/ether_ros/{slave}/inputs"


def outputs_topic(slave: str) -> str:
    return f"/ether_ros/{slave}/outputs"


class RecordingError(EtherRosError):
    """A recording cannot be written or read: names the file and what is wrong with it."""


# ---- what a recording describes ------------------------------------------------------------


@dataclass(frozen=True)
class VariableInfo:
    name: str
    type: str
    index: int
    subindex: int
    bit_length: int
    minimum: float
    maximum: float


@dataclass(frozen=True)
class SlaveInfo:
    name: str
    position: int
    device: str
    inputs: tuple[VariableInfo, ...]
    outputs: tuple[VariableInfo, ...]
    # Slave group and its cycle (recordings made before groups existed: "default", 0).
    group: str = "default"
    group_cycle_us: int = 0


@dataclass(frozen=True)
class BusInfo:
    name: str
    cycle_us: int
    slaves: tuple[SlaveInfo, ...]

    def slave(self, name: str) -> SlaveInfo:
        for s in self.slaves:
            if s.name == name:
                return s
        raise RecordingError(
            f"no slave {name!r} in the recording "
            f"(slaves: {', '.join(s.name for s in self.slaves) or 'none'})"
        )


@dataclass
class CycleTiming:
    """One cycle as the RT thread measured it (the engine's sample record)."""

    cycle: int
    t_wake_ns: int
    wake_latency_ns: int
    exec_ns: int
    period_ns: int
    rtt_ns: int
    working_counter: int
    flags: int
    dc_diff_ns: int


@dataclass
class CycleData:
    """Everything the recorder stores about one cycle."""

    timing: CycleTiming
    inputs: dict[str, Sequence[float]] = field(default_factory=dict)  # slave -> layout order
    outputs: dict[str, Sequence[float]] = field(default_factory=dict)
    raw_in: bytes = b""
    raw_out: bytes = b""
    expected_wkc: int = 0


# ---- writing -------------------------------------------------------------------------------


def _stamp(ns: int) -> dict[str, int]:
    return {"sec": ns // 1_000_000_000, "nanosec": ns % 1_000_000_000}


def _header(ns: int) -> dict[str, Any]:
    return {"stamp": _stamp(ns), "frame_id": ""}


class RecordingWriter:
    """Writes one recording. Not thread-safe: one thread (the recorder's) owns it."""

    def __init__(
        self,
        path: str | Path,
        bus: BusInfo,
        joints: Sequence[JointSpec] = (),
        metadata: dict[str, str] | None = None,
    ) -> None:
        from mcap_ros2.writer import Writer

        self.path = Path(path)
        self.bus = bus
        self.joints = list(joints)
        try:
            self._file: IO[bytes] = open(self.path, "wb")  # noqa: SIM115 (closed in close())
        except OSError as exc:
            raise RecordingError(f"cannot create recording {self.path}: {exc.strerror}") from exc
        self._writer = Writer(self._file)
        self._schemas = {
            name: self._writer.register_msgdef(name, text) for name, text in DEFINITIONS.items()
        }
        meta = {
            "format": FORMAT_NAME,
            "version": FORMAT_VERSION,
            "bus": bus.name,
            "cycle_us": str(bus.cycle_us),
        }
        meta.update(metadata or {})
        self._writer.add_metadata(METADATA_NAME, meta)
        self._joint_index = self._resolve_joints()
        self._timing: list[CycleTiming] = []
        self._last_ns = time.time_ns()
        self.cycles = 0
        self._closed = False
        self._write_layout()

    def _resolve_joints(self) -> list[tuple[JointSpec, int | None, int | None, int | None]]:
        resolved = []
        for joint in self.joints:
            names = [v.name for v in self.bus.slave(joint.slave).inputs]

            def find(
                var: str | None, joint: JointSpec = joint, names: list[str] = names
            ) -> int | None:
                if var is None:
                    return None
                if var not in names:
                    raise RecordingError(
                        f"joint {joint.name!r}: slave {joint.slave!r} has no input {var!r}"
                    )
                return names.index(var)

            resolved.append((joint, find(joint.position), find(joint.velocity), find(joint.effort)))
        return resolved

    def _write(self, topic: str, type_name: str, message: dict[str, Any], ns: int) -> None:
        self._writer.write_message(
            topic, self._schemas[type_name], message, log_time=ns, publish_time=ns
        )

    def _write_layout(self) -> None:
        def var(v: VariableInfo) -> dict[str, Any]:
            return {
                "name": v.name,
                "type": v.type,
                "index": v.index,
                "subindex": v.subindex,
                "bit_length": v.bit_length,
                "minimum": float(v.minimum),
                "maximum": float(v.maximum),
            }

        ns = self._last_ns
        self._write(
            TOPIC_LAYOUT,
            "ether_ros_msgs/msg/BusLayout",
            {
                "header": _header(ns),
                "bus": self.bus.name,
                "cycle_us": self.bus.cycle_us,
                "slaves": [
                    {
                        "slave": s.name,
                        "position": s.position,
                        "device": s.device,
                        "group": s.group,
                        "group_cycle_us": s.group_cycle_us,
                        "inputs": [var(v) for v in s.inputs],
                        "outputs": [var(v) for v in s.outputs],
                    }
                    for s in self.bus.slaves
                ],
            },
            ns,
        )

    def write_cycle(self, data: CycleData, ns: int | None = None) -> None:
        """Store one cycle. ``ns`` is the wall-clock log time (default: now).

        Timing is stored for every cycle; decoded values, joints and raw images only when the
        cycle carries them (the source decides the decimation).
        """
        ns = time.time_ns() if ns is None else ns
        self._last_ns = ns
        t = data.timing
        self._timing.append(t)
        if len(self._timing) >= TIMING_BATCH:
            self._flush_timing(ns)
        if data.inputs or data.outputs:
            self._write_values(t.cycle, data.inputs, data.outputs, ns)
            if self._joint_index:
                self._write_joints(data, ns)
        if data.raw_in or data.raw_out:
            self._write(
                TOPIC_RAW,
                "ether_ros_msgs/msg/PdoRaw",
                {
                    "header": _header(ns),
                    "cycle": t.cycle,
                    "working_counter": t.working_counter,
                    "expected_working_counter": data.expected_wkc,
                    "pdo_in": data.raw_in,
                    "pdo_out": data.raw_out,
                },
                ns,
            )
        self.cycles += 1

    def write_values(
        self,
        cycle: int,
        inputs: Mapping[str, Sequence[float]],
        outputs: Mapping[str, Sequence[float]],
        ns: int | None = None,
    ) -> None:
        """Store the decoded values of one cycle without its timing (slave -> values in layout
        order). For sources that see only decoded values, such as a ROS 2 client of the node:
        the recording then holds no loop timing rather than invented timing, and its time axis
        is cycle × period."""
        ns = time.time_ns() if ns is None else ns
        self._last_ns = ns
        self._write_values(cycle, inputs, outputs, ns)
        self.cycles += 1

    def _write_values(
        self,
        cycle: int,
        inputs: Mapping[str, Sequence[float]],
        outputs: Mapping[str, Sequence[float]],
        ns: int,
    ) -> None:
        for slave in self.bus.slaves:
            for topic, values in (
                (inputs_topic(slave.name), inputs.get(slave.name)),
                (outputs_topic(slave.name), outputs.get(slave.name)),
            ):
                if values is None:
                    continue
                self._write(
                    topic,
                    "ether_ros_msgs/msg/SlaveValues",
                    {
                        "header": _header(ns),
                        "slave": slave.name,
                        "position": slave.position,
                        "cycle": cycle,
                        "values": [float(x) for x in values],
                        "stale": False,  # the recorder's sources carry no freshness
                    },
                    ns,
                )

    def _write_joints(self, data: CycleData, ns: int) -> None:
        names: list[str] = []
        pos: list[float] = []
        vel: list[float] = []
        eff: list[float] = []
        for joint, ip, iv, ie in self._joint_index:
            values = data.inputs.get(joint.slave)
            if values is None:
                return
            names.append(joint.name)
            pos.append(
                values[ip] * joint.position_scale + joint.position_offset
                if ip is not None
                else float("nan")
            )
            vel.append(values[iv] * joint.velocity_scale if iv is not None else float("nan"))
            eff.append(values[ie] * joint.effort_scale if ie is not None else float("nan"))
        self._write(
            TOPIC_JOINTS,
            "sensor_msgs/msg/JointState",
            {"header": _header(ns), "name": names, "position": pos, "velocity": vel, "effort": eff},
            ns,
        )

    def _flush_timing(self, ns: int) -> None:
        if not self._timing:
            return
        ts = self._timing
        self._write(
            TOPIC_TIMING,
            "ether_ros_msgs/msg/CycleTimingBatch",
            {
                "header": _header(ns),
                "cycle": [t.cycle for t in ts],
                "t_wake_ns": [t.t_wake_ns for t in ts],
                "wake_latency_ns": [t.wake_latency_ns for t in ts],
                "exec_ns": [t.exec_ns for t in ts],
                "period_ns": [t.period_ns for t in ts],
                "rtt_ns": [t.rtt_ns for t in ts],
                "working_counter": [t.working_counter for t in ts],
                "flags": [t.flags for t in ts],
                "dc_diff_ns": [t.dc_diff_ns for t in ts],
            },
            ns,
        )
        self._timing = []

    def write_statistics(self, stats: dict[str, Any], ns: int | None = None) -> None:
        """The bus statistics (``Bus.stats()``) as one diagnostics status, values as text."""
        ns = time.time_ns() if ns is None else ns
        values = [{"key": str(k), "value": str(v)} for k, v in sorted(_flatten(stats).items())]
        self._write(
            TOPIC_DIAGNOSTICS,
            "diagnostic_msgs/msg/DiagnosticArray",
            {
                "header": _header(ns),
                "status": [
                    {
                        "level": 0,
                        "name": f"ether_ros: {self.bus.name}",
                        "message": "",
                        "hardware_id": self.bus.name,
                        "values": values,
                    }
                ],
            },
            ns,
        )

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        self._flush_timing(self._last_ns)
        self._writer.finish()
        self._file.close()

    def __enter__(self) -> RecordingWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _flatten(d: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    flat: dict[str, Any] = {}
    for key, value in d.items():
        name = f"{prefix}{key}"
        if isinstance(value, dict):
            flat.update(_flatten(value, name + "."))
        else:
            flat[name] = value
    return flat


# ---- recording a running bus ---------------------------------------------------------------


class SampleSource(Protocol):
    """What the recorder needs of a bus: cycles since the last call, and statistics."""

    def cycles(self) -> list[CycleData]: ...

    def stats(self) -> dict[str, Any]: ...


class Recorder:
    """Drains a :class:`SampleSource` into a :class:`RecordingWriter` in a background thread.

    The thread polls every ``poll_s`` (the engine's ring holds far more than that many cycles);
    it never blocks the RT thread, which drops samples (and counts them) if the ring fills up.
    """

    def __init__(
        self,
        source: SampleSource,
        writer: RecordingWriter,
        poll_s: float = 0.02,
        stats_period_s: float = 1.0,
    ) -> None:
        self.source = source
        self.writer = writer
        self.poll_s = poll_s
        self.stats_period_s = stats_period_s
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="ether_ros-recorder", daemon=True)
        self.error: BaseException | None = None

    def start(self) -> Recorder:
        self._thread.start()
        return self

    def _run(self) -> None:
        next_stats = time.monotonic()
        try:
            while True:
                stopping = self._stop.is_set()
                for data in self.source.cycles():
                    self.writer.write_cycle(data)
                if time.monotonic() >= next_stats or stopping:
                    self.writer.write_statistics(self.source.stats())
                    next_stats = time.monotonic() + self.stats_period_s
                if stopping:
                    return
                self._stop.wait(self.poll_s)
        except BaseException as exc:  # reported by stop(); the RT side is unaffected
            self.error = exc

    def stop(self) -> None:
        """Drain what is left, write the statistics once more and close the file."""
        self._stop.set()
        self._thread.join()
        self.writer.close()
        if self.error is not None:
            if isinstance(self.error, EtherRosError):
                raise self.error
            raise RecordingError(f"recording to {self.writer.path} failed: {self.error!r}")

    def __enter__(self) -> Recorder:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()


# ---- reading -------------------------------------------------------------------------------


@dataclass
class Series:
    """Decoded values of one slave direction: ``cycle`` and a column per variable."""

    cycle: np.ndarray
    log_time_s: np.ndarray
    columns: dict[str, np.ndarray]

    def __getitem__(self, name: str) -> np.ndarray:
        try:
            return self.columns[name]
        except KeyError:
            raise RecordingError(
                f"no variable {name!r} in the recording (variables: {', '.join(self.columns)})"
            ) from None


@dataclass
class Recording:
    path: Path
    metadata: dict[str, str]
    bus: BusInfo
    timing: dict[str, np.ndarray]  # field name -> one entry per cycle
    inputs: dict[str, Series]  # slave -> series
    outputs: dict[str, Series]
    joints: dict[str, np.ndarray]  # "name", "time_s", "position", "velocity", "effort"
    statistics: list[dict[str, str]]

    @property
    def cycle_s(self) -> float:
        return self.bus.cycle_us * 1e-6

    def wake_times_s(self, cycles: np.ndarray) -> np.ndarray:
        """When the given cycles ran, in seconds since the first recorded cycle.

        From each cycle's measured wake-up time, so skipped cycles (overruns) do not stretch
        or squeeze the time axis; cycle × period from the recording's first cycle when the
        timing is not in the recording (one time origin for every series)."""
        cycles = np.asarray(cycles, dtype=np.int64)
        known = self.timing.get("cycle")
        wake = self.timing.get("t_wake_ns")
        if known is None or wake is None or known.size == 0:
            firsts = [
                int(s.cycle.min())
                for series in (self.inputs, self.outputs)
                for s in series.values()
                if s.cycle.size
            ]
            first = min(firsts) if firsts else (int(cycles.min()) if cycles.size else 0)
            return (cycles - first) * self.cycle_s
        t = (wake.astype(np.int64) - int(wake[0])) * 1e-9
        return np.interp(cycles.astype(float), known.astype(float), t)

    def lost_frames(self) -> int:
        flags = self.timing.get("flags")
        return 0 if flags is None else int(np.count_nonzero(flags & FLAG_LOST))


def _check_ours(path: Path) -> dict[str, str]:
    from mcap.exceptions import McapError
    from mcap.reader import make_reader

    try:
        with open(path, "rb") as fh:
            reader = make_reader(fh)
            header = reader.get_header()
            summary = reader.get_summary()
            metadata = {m.name: dict(m.metadata) for m in reader.iter_metadata()}
    except FileNotFoundError as exc:
        raise RecordingError(f"recording {path} does not exist") from exc
    except IsADirectoryError as exc:
        raise RecordingError(f"{path} is a directory, not a recording") from exc
    except (
        McapError,
        ValueError,
        EOFError,
        AssertionError,
        KeyError,
        OSError,
        struct.error,
    ) as exc:
        if _has_mcap_magic(path):
            raise RecordingError(
                f"recording {path} is truncated or damaged; was the "
                "recorder stopped before it could close the file?"
            ) from exc
        raise RecordingError(f"{path} is not an MCAP recording") from exc
    if summary is None:
        raise RecordingError(
            f"recording {path} is truncated (no summary section); was the "
            "recorder stopped before it could close the file?"
        )
    meta = metadata.get(METADATA_NAME)
    if header.profile != "ros2" or meta is None or meta.get("format") != FORMAT_NAME:
        raise RecordingError(f"{path} is an MCAP file but not an ether_ros recording")
    if meta.get("version") != FORMAT_VERSION:
        raise RecordingError(
            f"recording {path} has format version {meta.get('version')}; this "
            f"ether-ros reads version {FORMAT_VERSION}"
        )
    return meta


def _has_mcap_magic(path: Path) -> bool:
    try:
        with open(path, "rb") as fh:
            return fh.read(8) == b"\x89MCAP0\r\n"
    except OSError:
        return False


def read_recording(path: str | Path) -> Recording:
    """Load a recording written by :class:`RecordingWriter` into arrays."""
    from mcap.exceptions import McapError
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    path = Path(path)
    meta = _check_ours(path)
    bus: BusInfo | None = None
    timing_parts: dict[str, list[Any]] = {}
    values: dict[str, dict[str, list[tuple[int, float, Sequence[float]]]]] = {
        "inputs": {},
        "outputs": {},
    }
    joints: list[tuple[float, list[str], Any, Any, Any]] = []
    stats: list[dict[str, str]] = []
    try:
        with open(path, "rb") as fh:
            reader = make_reader(fh, decoder_factories=[DecoderFactory()])
            for _schema, channel, message, msg in reader.iter_decoded_messages(log_time_order=True):
                topic = channel.topic
                t = message.log_time * 1e-9
                if topic == TOPIC_LAYOUT:
                    bus = _bus_from_msg(msg)
                elif topic == TOPIC_TIMING:
                    for name in (
                        "cycle",
                        "t_wake_ns",
                        "wake_latency_ns",
                        "exec_ns",
                        "period_ns",
                        "rtt_ns",
                        "working_counter",
                        "flags",
                        "dc_diff_ns",
                    ):
                        timing_parts.setdefault(name, []).append(np.asarray(getattr(msg, name)))
                elif topic.endswith(("/inputs", "/outputs")) and topic.startswith("/ether_ros/"):
                    kind = topic.rsplit("/", 1)[1]
                    values[kind].setdefault(msg.slave, []).append((msg.cycle, t, msg.values))
                elif topic == TOPIC_JOINTS:
                    joints.append((t, list(msg.name), msg.position, msg.velocity, msg.effort))
                elif topic == TOPIC_DIAGNOSTICS:
                    for status in msg.status:
                        stats.append({kv.key: kv.value for kv in status.values})
    except (McapError, ValueError, EOFError, KeyError, struct.error) as exc:
        raise RecordingError(f"recording {path} is damaged: {exc}") from exc
    if bus is None:
        raise RecordingError(f"recording {path} has no bus layout ({TOPIC_LAYOUT})")
    timing = {k: np.concatenate(v) for k, v in timing_parts.items()}
    if timing:
        order = np.argsort(timing["cycle"], kind="stable")
        timing = {k: v[order] for k, v in timing.items()}
    series: dict[str, dict[str, Series]] = {"inputs": {}, "outputs": {}}
    for kind in ("inputs", "outputs"):
        for slave_name, rows in values[kind].items():
            slave = bus.slave(slave_name)
            names = [v.name for v in (slave.inputs if kind == "inputs" else slave.outputs)]
            matrix = np.array([r[2] for r in rows], dtype=float).reshape(len(rows), len(names))
            series[kind][slave_name] = Series(
                cycle=np.array([r[0] for r in rows], dtype=np.uint64),
                log_time_s=np.array([r[1] for r in rows]),
                columns={n: matrix[:, i] for i, n in enumerate(names)},
            )
    joint_data: dict[str, np.ndarray] = {}
    if joints:
        joint_data = {
            "name": np.array(joints[0][1]),
            "time_s": np.array([j[0] for j in joints]),
            "position": np.array([j[2] for j in joints], dtype=float),
            "velocity": np.array([j[3] for j in joints], dtype=float),
            "effort": np.array([j[4] for j in joints], dtype=float),
        }
    return Recording(
        path, meta, bus, timing, series["inputs"], series["outputs"], joint_data, stats
    )


def _bus_from_msg(msg: Any) -> BusInfo:
    def var(v: Any) -> VariableInfo:
        return VariableInfo(v.name, v.type, v.index, v.subindex, v.bit_length, v.minimum, v.maximum)

    return BusInfo(
        msg.bus,
        msg.cycle_us,
        tuple(
            SlaveInfo(
                s.slave,
                s.position,
                s.device,
                tuple(var(v) for v in s.inputs),
                tuple(var(v) for v in s.outputs),
                getattr(s, "group", "default") or "default",
                int(getattr(s, "group_cycle_us", 0)),
            )
            for s in msg.slaves
        ),
    )


def write_recording(
    path: str | Path,
    bus: BusInfo,
    cycles: Iterable[CycleData],
    cycle_ns: Callable[[CycleData], int] | None = None,
    **kw: Any,
) -> Path:
    """Write a whole recording from an iterable of cycles (tests, converters)."""
    with RecordingWriter(path, bus, **kw) as writer:
        for data in cycles:
            writer.write_cycle(data, cycle_ns(data) if cycle_ns else None)
    return Path(path)
