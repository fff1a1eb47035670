"""The ROS 2 demo: the thesis's trot (Table 6.1) on four simulated Laelaps II legs, driven
through ROS 2 only.

1. A veth pair; the simulator (``ether-ros sim``) on one end, in its own process.
2. The node (``ether-ros run``) on the other end, in its own process: OP, cyclic exchange at
   2.5 kHz, publishing.
3. This process is a plain rclpy client: it publishes the writes of the trot sequence on
   ``pdo_listener`` (``python/ether_ros/console/sequences/trot.yaml``: standing, b to 4 cm, a to
   5 cm over the 3 s transition time, phases FL 180 / FR 0 / HL 0 / HR 180, hold, a and b back
   to 0) and subscribes to ``pdo_in``, ``joint_states`` and ``diagnostics``. A step that sets
   several variables of a slave goes through ``write_variables`` instead, as the console sends
   it: the master checks a leg's trajectory record as a whole (its workspace), and the values
   of one step are only valid together (the first leg step sets the centre with the rest).
4. A summary: per leg the RMS tracking error of hip and knee (desired vs measured angle, as the
   slaves report them) while trotting, whether diagonal legs move together, lost frames, loop
   timing and DC sync error from the node's diagnostics.
5. The run as the thesis shows it: everything received on ``pdo_in``/``pdo_out`` is written to
   ``OUTPUT/trot.mcap`` (decoded values only: a ROS 2 client sees no loop timing), Figs.
   6.5–6.11 of that run go to ``OUTPUT/*.png`` (``ether-ros plot``'s figures) and the
   steady-trot report (share of time at the PWM limit per leg and joint, toe path error) is
   printed.

Run: ``python -m ether_ros.demo.trot [CONFIG] [--output DIR]`` as root (about a minute).
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

from ether_ros_msgs.msg import SlaveValues

from ether_ros.console.commands import ConsoleContext, Control, Wait, Write
from ether_ros.console.sequence import Sequence, load_sequence
from ether_ros.errors import EtherRosError
from ether_ros.ros.client import EtherRosClient, make_write
from ether_ros.ros.layout import BusSpec, VariableSpec
from ether_ros.ros.rig import RosRig
from ether_ros.tools.recording import BusInfo, Recording, SlaveInfo, VariableInfo

REPO = Path(__file__).resolve().parents[3]
DEFAULT_CONFIG = REPO / "config" / "laelaps.yaml"
DEFAULT_OUTPUT = Path("demo-output")
ANGLES = ("hip_angle", "desired_hip_angle", "knee_angle", "desired_knee_angle")
# An RMS error below this: the leg follows its trajectory. Loosely, as the thesis's legs did
# (§6.2.2.1: low gains, no I term, the ground; the twin's hips lag by ~4-5° RMS).
TRACKED_DEG = 8.0


@dataclass
class LegTrace:
    """Angles (deg) a leg reported while the trot was held."""

    hip_err: list[float] = field(default_factory=list)
    knee_err: list[float] = field(default_factory=list)
    desired_knee: dict[int, float] = field(default_factory=dict)  # by cycle

    def rms(self, values: list[float]) -> float:
        return math.sqrt(sum(v * v for v in values) / len(values)) if values else math.nan


class TrotRecorder:
    """Collects the decoded inputs of every leg while ``recording`` is set, and every decoded
    input and output the node publishes for the recording of the whole run."""

    def __init__(self) -> None:
        self.layout: BusSpec | None = None
        self.recording = threading.Event()
        self.legs: dict[str, LegTrace] = {}
        self._index: dict[str, list[int]] = {}
        self._lock = threading.Lock()
        # cycle -> slave -> values, as received
        self.inputs: dict[int, dict[str, list[float]]] = {}
        self.outputs: dict[int, dict[str, list[float]]] = {}

    def set_layout(self, layout: BusSpec) -> None:
        self.layout = layout
        for s in layout.slaves:
            names = [v.name for v in s.inputs]
            if all(a in names for a in ANGLES):
                self._index[s.name] = [names.index(a) for a in ANGLES]
                self.legs[s.name] = LegTrace()

    def on_outputs(self, msg: SlaveValues) -> None:
        if self.layout is None:
            return
        with self._lock:
            self.outputs.setdefault(int(msg.cycle), {})[msg.slave] = list(msg.values)

    def received(
        self,
    ) -> tuple[dict[int, dict[str, list[float]]], dict[int, dict[str, list[float]]]]:
        """Copies of the inputs and outputs received so far: cycle -> slave -> values."""
        with self._lock:
            return dict(self.inputs), dict(self.outputs)

    def on_inputs(self, msg: SlaveValues) -> None:
        if self.layout is not None:
            with self._lock:
                self.inputs.setdefault(int(msg.cycle), {})[msg.slave] = list(msg.values)
        if not self.recording.is_set() or msg.slave not in self._index:
            return
        hip, want_hip, knee, want_knee = (msg.values[i] / 100.0 for i in self._index[msg.slave])
        with self._lock:
            trace = self.legs[msg.slave]
            trace.hip_err.append(want_hip - hip)
            trace.knee_err.append(want_knee - knee)
            trace.desired_knee[int(msg.cycle)] = want_knee


def correlation(x: dict[int, float], y: dict[int, float]) -> float:
    """Pearson correlation of two legs' values over the cycles both were received."""
    common = sorted(x.keys() & y.keys())
    n = len(common)
    if n < 10:
        return math.nan
    a, b = [x[c] for c in common], [y[c] for c in common]
    ma, mb = sum(a) / n, sum(b) / n
    cov = sum((x - ma) * (y - mb) for x, y in zip(a, b, strict=True))
    va = sum((x - ma) ** 2 for x in a)
    vb = sum((y - mb) ** 2 for y in b)
    return cov / math.sqrt(va * vb) if va > 0 and vb > 0 else math.nan


def run_sequence(client: EtherRosClient, sequence: Sequence, recorder: TrotRecorder) -> None:
    """Publish every write of the sequence on ``pdo_listener`` (a step setting several
    variables of one slave through ``write_variables``) and check its result; record while the
    full ellipse (a = 5 cm) is held."""
    for step in sequence.steps:
        command = step.command
        print(f"  [{step.number:2}/{len(sequence.steps)}] {step.text}", flush=True)
        if isinstance(command, Write):
            if len({op.slave for op in command.ops}) < len(command.ops):
                # Several variables of one slave: checked together, all or nothing.
                writes = [make_write(op.slave, op.variable, op.value) for op in command.ops]
                ok, message = client.write_many(writes)
                if not ok:
                    raise EtherRosError(f"step {step.number} refused: {message}")
            else:
                ids = [client.publish_write(op.slave, op.variable, op.value) for op in command.ops]
                for request_id in ids:
                    result = client.wait_result(request_id, timeout=5.0)
                    if not result.success:
                        raise EtherRosError(f"step {step.number} refused: {result.message}")
            variables = {(op.variable, op.value) for op in command.ops}
            if ("a_ellipse100", 5.0) in variables:
                recorder.recording.set()
            if ("a_ellipse100", 0.0) in variables:
                recorder.recording.clear()
        elif isinstance(command, Wait):
            time.sleep(command.seconds)
        elif isinstance(command, Control):
            ok, message = client.command(command.command)
            if not ok:
                raise EtherRosError(f"step {step.number}: {message}")


def summary(client: EtherRosClient, recorder: TrotRecorder) -> tuple[str, bool]:
    lines = ["", "Trot summary (while a = 5 cm, b = 4 cm were held; angles in degrees)"]
    lines.append(f"  {'leg':18} {'samples':>7} {'RMS hip':>8} {'RMS knee':>9}  tracked")
    all_tracked = True
    for leg, trace in recorder.legs.items():
        hip, knee = trace.rms(trace.hip_err), trace.rms(trace.knee_err)
        tracked = bool(trace.hip_err) and hip < TRACKED_DEG and knee < TRACKED_DEG
        all_tracked &= tracked
        lines.append(
            f"  {leg:18} {len(trace.hip_err):7} {hip:8.2f} {knee:9.2f}  "
            f"{'yes' if tracked else 'NO'}"
        )
    legs = recorder.legs
    pairs = [("front_left_leg", "hind_right_leg"), ("front_right_leg", "hind_left_leg"),
             ("front_left_leg", "front_right_leg")]  # fmt: skip
    for a, b in pairs:
        if a in legs and b in legs:
            r = correlation(legs[a].desired_knee, legs[b].desired_knee)
            lines.append(f"  desired knee angle correlation {a} / {b}: {r:+.2f}")
    lines.extend(bus_lines(client))
    return "\n".join(lines), all_tracked


def bus_lines(client: EtherRosClient) -> list[str]:
    """The bus part of a demo's summary, from the node's diagnostics: slave states, cycle
    counters, loop timing and DC sync error."""
    lines = []
    status = client.master_status()
    states = client.slave_states()
    lines.append("Bus (from the node's diagnostics)")
    lines.append(
        "  slaves                       "
        + ", ".join(f"{name} {state}" for name, state in states.items())
    )
    for key, label in (
        ("cycles", "cycles"),
        ("lost_frames", "lost frames"),
        ("late_frames", "late frames"),
        ("wkc_errors", "working counter errors"),
        ("overruns", "overruns"),
        ("ros_dropped", "samples dropped by ROS"),
    ):
        lines.append(f"  {label:28} {status.get(key, '?')}")
    for key, label in (
        ("wake_latency", "wake-up latency"),
        ("period", "period"),
        ("rtt", "frame round trip"),
        ("exec", "execution"),
    ):
        p50, p99, mx = (status.get(f"{key}_{q}_ns", "") for q in ("p50", "p99", "max"))
        if p50:
            lines.append(
                f"  {label:28} p50 {int(p50) / 1000:7.1f} µs  p99 {int(p99) / 1000:7.1f} µs  "
                f"max {int(mx) / 1000:8.1f} µs"
            )
    if "dc_sync_error_max_ns" in status:
        dc = int(status["dc_sync_error_max_ns"]) / 1000
        lines.append(f"  {'DC sync error (last period)':28} max {dc:.1f} µs")
    return lines


def bus_info(layout: BusSpec) -> BusInfo:
    """The recording's description of the bus, from the layout the node publishes."""

    def variables(vs: tuple[VariableSpec, ...]) -> tuple[VariableInfo, ...]:
        return tuple(
            VariableInfo(v.name, v.type, v.index, v.subindex, v.bit_length, v.minimum, v.maximum)
            for v in vs
        )

    return BusInfo(
        layout.bus,
        layout.cycle_us,
        tuple(
            SlaveInfo(
                s.name,
                s.position,
                s.device,
                variables(s.inputs),
                variables(s.outputs),
                s.group,
                s.group_cycle_us,
            )
            for s in layout.slaves
        ),
    )


def save_run(recorder: TrotRecorder, output: Path) -> list[Path]:
    """Write what the client received to ``output/trot.mcap``, the figures of the run next to
    it (PNG) and print the steady-trot report. Returns the files written."""
    import matplotlib

    matplotlib.use("Agg")
    from ether_ros.tools.plots import build_figures, save_figures
    from ether_ros.tools.recording import RecordingWriter, read_recording
    from ether_ros.tools.trot_metrics import format_trot_report, trot_report

    if recorder.layout is None:
        raise EtherRosError("the node never published its bus layout: nothing to record")
    try:
        output.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise EtherRosError(f"cannot create the output directory {output}: {exc.strerror}") from exc
    path = output / "trot.mcap"
    inputs, outputs = recorder.received()
    cycles = sorted(inputs.keys() | outputs.keys())
    cycle_ns = recorder.layout.cycle_us * 1000
    start_ns = time.time_ns() - (cycles[-1] - cycles[0]) * cycle_ns if cycles else 0
    with RecordingWriter(
        path, bus_info(recorder.layout), metadata={"experiment": "trot", "source": "ROS 2 demo"}
    ) as writer:
        for cycle in cycles:
            ns = start_ns + (cycle - cycles[0]) * cycle_ns
            writer.write_values(cycle, inputs.get(cycle, {}), outputs.get(cycle, {}), ns)
    rec = read_recording(path)
    written = [path, *save_figures(build_figures(rec), output, ("png",))]
    print(format_trot_report(trot_report(rec)))
    sparse = sparse_share(rec)
    if sparse > 0.5:
        print(
            f"note: {100 * sparse:.0f} % of the node's decoded samples never reached this client "
            "(the node drops what it cannot publish in time on a loaded host: 'samples dropped "
            "by ROS' above); the figures and the report have gaps accordingly. `ether-ros "
            "experiment trot --record` records every sample on the master's side."
        )
    return written


def sparse_share(rec: Recording) -> float:
    """The share of decoded samples missing from the recording: the node publishes every
    ``ros.decoded_decimation`` cycles, the smallest step between two received cycles."""
    import numpy as np

    steps = [np.diff(s.cycle.astype(np.int64)) for s in rec.inputs.values() if s.cycle.size > 2]
    if not steps:
        return 0.0
    every = np.concatenate(steps)
    decimation = int(every[every > 0].min()) if np.any(every > 0) else 1
    expected = sum(int(s.cycle[-1] - s.cycle[0]) // decimation + 1 for s in rec.inputs.values())
    received = sum(s.cycle.size for s in rec.inputs.values())
    return max(0.0, 1.0 - received / expected) if expected else 0.0


def run_demo(
    config: Path = DEFAULT_CONFIG, sequence: str = "trot", output: Path = DEFAULT_OUTPUT
) -> int:
    if os.geteuid() != 0:
        print("ether_ros demo: needs root (it creates a veth pair)", file=sys.stderr)
        return 2
    recorder = TrotRecorder()
    started = time.monotonic()
    print(f"ether_ros demo: simulator + node on a veth pair ({config.name}) ...", flush=True)
    options = {"on_inputs": recorder.on_inputs, "on_outputs": recorder.on_outputs}
    with RosRig(config, client_options=options) as rig:
        client = rig.client
        state = client.wait_for_node()
        layout = client.layout(timeout=10)
        recorder.set_layout(layout)
        print(
            f"node {client.target} {state}: {len(layout.slaves)} slaves "
            f"({', '.join(s.name for s in layout.slaves)}), cycle {layout.cycle_us} µs",
            flush=True,
        )
        zero = {s.name: {v.name: 0.0 for v in s.outputs} for s in layout.slaves}
        seq = load_sequence(sequence, ConsoleContext(layout, zero))
        print(f"sequence {seq.description or seq.path} ({seq.duration_s:g} s):", flush=True)
        run_sequence(client, seq, recorder)
        client.wait_for(lambda latest: latest.counts.get("diagnostics", 0) >= 2, 3.0)
        text, tracked = summary(client, recorder)
    print(text)
    print("", flush=True)
    written = save_run(recorder, output)
    print(f"\nThis run's recording and figures (Figs. 6.5-6.11) are in {output}/:")
    for p in written:
        print(f"  {p}")
    print(f"demo finished in {time.monotonic() - started:.0f} s", flush=True)
    return 0 if tracked else 1


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m ether_ros.demo.trot", description=__doc__)
    parser.add_argument("config", nargs="?", default=str(DEFAULT_CONFIG))
    parser.add_argument("--sequence", default="trot", help="sequence file or packaged name")
    parser.add_argument(
        "--output", default=str(DEFAULT_OUTPUT), help="where the recording and figures go"
    )
    args = parser.parse_args(argv)
    try:
        return run_demo(Path(args.config), args.sequence, Path(args.output))
    except EtherRosError as exc:
        print(f"ether_ros demo: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
