"""CiA 402 trajectories: start skew across the six joints of the arm and tracking error, through
the Python API (``Bus.follow``, one hand-over for all joints) and through the node's
``FollowJointTrajectory`` action server driven by a separate rclpy action client, in the same run.

Setup (nothing faked): config/arm6.yaml — three simulated two-axis ServoDrive2, 1 kHz, DC —
with ``ether-ros sim`` in its own network namespace across a veth pair.

- API: this process opens the bus (``Bus.open`` + ``bus.start``), enables the six axes and hands
  the trajectory to ``bus.follow``.
- FJT: ``RosRig`` runs the simulator and the node (``ether-ros run``) as their own processes;
  this process is the rclpy action client (``TrajectoryActionClient``; it enables the axes
  through the same client node, so it is also the control lease's holder where the
  configuration turns the lease on).

Both paths are recorded the same way: every cycle's LRW reply frame, captured on the master's
end of the veth pair (``WireRecorder``), holds the targets sent and the actual positions of that
cycle. (The node's ``pdo_raw`` skips batches of cycles on a loaded host; the engine's samples pair
a cycle's outputs with the previous frame's inputs, one cycle more lag than the wire shows.) The
API's start cycles are also read from ``bus.samples()``, as a cross-check.

The same trajectory both ways: every joint ``(3A/k) sin(2πkt/T)·(1 − (t/T)²)`` with A = 0.3 rad,
k = 1..3 (amplitudes 0.9, 0.45, 0.3 rad: the same speed at the start), alternating signs,
T = 3 s, as points every 10 ms
with positions and velocities; it starts at rest at 0 (a first point at time 0, as a planner
sends the arm's state), leaves it at once (every joint's target moves in its first cycle) and
ends at rest at 0.

Start cycle of a joint: the first recorded cycle whose target position (the output image's
0x607A) differs from the one before the trajectory; skew = max − min over the six joints.
Tracking error: target position sent in a cycle minus the actual position (0x6064) read in the
same cycle, over the trajectory's cycles from the first start; RMS and max per joint and overall.
Three rounds per path (``--quick``: one); about a minute and a half.
"""

from __future__ import annotations

import math
import socket
import struct
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from report import BenchSkipped, Report

REPO = Path(__file__).resolve().parent.parent
CONFIG = REPO / "config" / "arm6.yaml"
JOINTS = ["shoulder_pan", "shoulder_lift", "elbow", "wrist_1", "wrist_2", "wrist_3"]
# rad, for k = 3; joint j's amplitude is AMPLITUDE·3/k, so every joint leaves its start with
# the same speed and its target moves by the same number of counts in the first cycle (the
# start cycle is where a target first changes: a joint whose first step rounds to 0 counts
# would look a cycle late).
AMPLITUDE = 0.3
STEP = 0.01  # s between trajectory points
DURATION = 3.0  # s (1.9 rad/s at most for every joint, within every joint's limit)
# s both paths' trajectories start after the call: the API's start_in, the FJT goal's
# header.stamp (wall clock now + HOLD).
HOLD = 0.05


# ---------------------------------------------------------------------------- pure helpers
def trajectory(duration: float, step: float = STEP) -> dict[str, list[tuple[float, float, float]]]:
    """Per joint, points (t, position, velocity) from 0 to ``duration`` every ``step``: joint j
    follows ``±(3A/k) sin(2πkt/T)(1 − (t/T)²)``, k = 1 + j % 3, sign alternating (the same
    speed for every joint at the start); ends at rest at 0.
    The first point is the state the arm starts in (at rest at 0, time 0), as a planner such as
    MoveIt sends it. Without it, both paths interpolate from the state the trajectory found
    when the engine took it over to the first point, 10 ms after the start: a segment whose
    length depends on when the hand-over happened (the FJT goal arrives later than the API's
    call), and which asks for more acceleration than the trajectory itself (measured: 20 mrad
    of error 6 ms after the start through FJT, against 11 mrad at most through the API)."""
    n = round(duration / step)
    out: dict[str, list[tuple[float, float, float]]] = {}
    for j, name in enumerate(JOINTS):
        k = 1 + j % 3
        a = AMPLITUDE * 3 / k * (1 if j % 2 == 0 else -1)
        w = 2 * math.pi * k / duration
        points = [(0.0, 0.0, 0.0)]
        for i in range(1, n + 1):
            t = i * step
            u = 1 - (t / duration) ** 2
            p = a * math.sin(w * t) * u
            v = a * (w * math.cos(w * t) * u - math.sin(w * t) * 2 * t / duration**2)
            points.append((t, p, v))
        points[-1] = (duration, 0.0, 0.0)  # exactly at rest (u = 0 there; no rounding)
        out[name] = points
    return out


@dataclass
class StartCycles:
    """The cycle at which each joint's target first left its start; ``exact[j]``: the cycle
    before it was recorded too (a gap in the recording could hide an earlier start)."""

    cycles: list[int]
    exact: list[bool]

    @property
    def skew(self) -> int:
        return max(self.cycles) - min(self.cycles)


def start_cycles(cycles: npt.NDArray[Any], targets: npt.NDArray[Any]) -> StartCycles:
    """``cycles`` (n,) increasing cycle numbers of the recorded samples, ``targets`` (n, joints)
    the target positions (raw counts) of those cycles; the first sample is before the start.
    A joint that never leaves its start is a ValueError."""
    if len(cycles) != len(targets) or len(cycles) < 2:
        raise ValueError(f"{len(cycles)} cycles for {len(targets)} target rows (need >= 2)")
    moved = targets != targets[0]
    found, exact = [], []
    for j in range(targets.shape[1]):
        idx = np.flatnonzero(moved[:, j])
        if not len(idx):
            raise ValueError(f"joint {j}: its target never leaves {targets[0, j]}")
        i = int(idx[0])
        found.append(int(cycles[i]))
        exact.append(int(cycles[i - 1]) == int(cycles[i]) - 1)
    return StartCycles(found, exact)


@dataclass
class Tracking:
    rms: list[float]  # per joint
    max: list[float]
    rms_all: float
    max_all: float
    samples: int
    p99_all: float = 0.0  # 99th percentile of |error| over all joints


def tracking(errors: npt.NDArray[Any]) -> Tracking:
    """RMS and max |error| per joint (columns) and over all of them."""
    e = np.abs(np.asarray(errors, dtype=float))
    if e.ndim != 2 or not e.shape[0]:
        raise ValueError(f"errors must be (samples, joints) with samples, got {e.shape}")
    return Tracking(
        rms=[float(x) for x in np.sqrt((e**2).mean(axis=0))],
        max=[float(x) for x in e.max(axis=0)],
        rms_all=float(np.sqrt((e**2).mean())),
        max_all=float(e.max()),
        samples=int(e.shape[0]),
        p99_all=float(np.percentile(e, 99)),
    )


# ---------------------------------------------------------------------------- image fields
@dataclass
class Fields:
    """Where each joint's target and actual position sit in the process image."""

    target: list[int]
    actual: list[int]
    scale: list[float]
    image_len: int
    cycle_ns: int
    lrw: dict[str, int]

    @classmethod
    def of(cls, bus: Any) -> Fields:
        entries = {e.name: e for e in bus.plan.axes}
        return cls(
            target=[entries[j].map.target_position for j in JOINTS],
            actual=[entries[j].map.position for j in JOINTS],
            scale=[entries[j].position_scale for j in JOINTS],
            image_len=bus.layout.image_len,
            cycle_ns=bus.cycle_ns,
            lrw=_the_lrw(bus.plan),
        )

    def read(self, images: npt.NDArray[np.uint8], offsets: list[int]) -> npt.NDArray[np.int64]:
        cols = [
            np.ascontiguousarray(images[:, o : o + 4]).view("<i4")[:, 0].astype(np.int64)
            for o in offsets
        ]
        return np.stack(cols, axis=1)


def _the_lrw(plan: Any) -> dict[str, int]:
    """The plan's one LRW datagram (arm6: one frame, one LRW over the whole image)."""
    lrws = [d for f in plan.frames for d in f.datagrams if d.kind == "lrw"]
    if len(lrws) != 1:
        raise RuntimeError(f"the benchmark reads one LRW per cycle; the plan has {len(lrws)}")
    return {k: int(getattr(lrws[0], k)) for k in ("address", "length", "image_offset")}


@dataclass
class Run:
    starts: StartCycles
    errors: npt.NDArray[np.float64]  # (cycles, joints), rad
    gaps: int  # cycles missing from the recording within the trajectory
    offsets: npt.NDArray[np.int64]  # each error row's cycle, counted from the first start


def analyse(
    fields: Fields, cycles: npt.NDArray[Any], images: npt.NDArray[np.uint8], duration_cycles: int
) -> Run:
    targets = fields.read(images, fields.target)
    actuals = fields.read(images, fields.actual)
    starts = start_cycles(cycles, targets)
    first = min(starts.cycles)
    window = (cycles >= first) & (cycles < first + duration_cycles)
    errors = (targets[window] - actuals[window]) * np.asarray(fields.scale)
    offsets = (cycles[window] - first).astype(np.int64)
    return Run(starts, errors, duration_cycles - int(np.count_nonzero(window)), offsets)


def worst_at(runs: list[Run]) -> tuple[int, int]:
    """(cycles after the first start, joint) of the largest |error| over the runs."""
    best = (-1.0, 0, 0)
    for r in runs:
        e = np.abs(r.errors)
        row, joint = np.unravel_index(int(np.argmax(e)), e.shape)
        if e[row, joint] > best[0]:
            best = (float(e[row, joint]), int(r.offsets[row]), int(joint))
    return best[1], best[2]


# ---------------------------------------------------------------------------- the API path
def api_runs(
    fields_out: list[Fields], rounds: int, duration: float
) -> tuple[list[Run], list[StartCycles]]:
    """The wire's runs (as for FJT) and, as a cross-check, the start cycles the engine's own
    samples (``bus.samples()``) show."""
    from ether_ros.config import load_bus_config
    from ether_ros.master import Bus
    from ether_ros.sim.proof import SimProcess
    from ether_ros.testing.netns import VethPair

    track = trajectory(duration)
    runs, from_samples = [], []
    with VethPair.create(netns=True) as veth, SimProcess(CONFIG, veth.slave, veth.netns):
        cfg = load_bus_config(CONFIG, interface=veth.master)
        with Bus.open(cfg, drift_frames=500) as bus:
            bus.start()
            fields = Fields.of(bus)
            fields_out.append(fields)
            cycles_of_run = round(duration * 1e9 / fields.cycle_ns)
            recorder = WireRecorder(veth.master, fields.lrw, fields.image_len)
            try:
                for a in bus.axes():
                    a.enable(timeout=10)
                home = {a.name: [(1.0, 0.0, 0.0)] for a in bus.axes()}
                for _ in range(rounds):
                    _api_wait(bus, bus.follow(home, start_in=HOLD), 1.0)
                    time.sleep(0.2)
                    bus.samples()  # drop what came before
                    recorder.on = True
                    start = bus.follow(track, start_in=HOLD)
                    records, images = _api_wait(bus, start, duration)
                    time.sleep(0.1)
                    recorder.on = False
                    from_samples.append(analyse(fields, records, images, cycles_of_run).starts)
                    runs.append(analyse(fields, *recorder.take(), cycles_of_run))
            finally:
                recorder.close()
    return runs, from_samples


def _api_wait(bus: Any, start: float, duration: float) -> tuple[Any, Any]:
    """Drain the samples (feeding the watchdog) until every axis has run its trajectory."""
    cycles, images = [], []
    deadline = time.monotonic() + duration + 30
    while True:
        s = bus.samples()
        cycles.append(s.records["cycle"].copy())
        images.append(s.images.copy())
        bus.feed_watchdog()
        if bus.engine.now_ns() / 1e9 > start + duration and all(
            a.status()["trajectory_done"] and not a.status()["trajectory_active"]
            for a in bus.axes()
        ):
            break
        if time.monotonic() > deadline:
            raise RuntimeError("the API trajectory did not finish")
        time.sleep(0.05)
    return np.concatenate(cycles), np.concatenate(images)


# ---------------------------------------------------------------------------- the FJT path
LRW = 0x0C
ETHERCAT = b"\x88\xa4"
CYCLIC_INDICES = (
    128  # the engine numbers its cyclic frames modulo 128 (crates/engine/src/cyclic.rs)
)


class WireRecorder:
    """Every reply frame of the cyclic LRW as it comes back to the master's end of the veth pair
    (the node's own ``pdo_raw`` cannot keep up with 1 kHz on a loaded host: it skips batches).
    A reply carries the outputs as sent and the drives' inputs of that cycle; its datagram index
    (the frame's number modulo 128) numbers the cycles."""

    def __init__(self, interface: str, lrw: dict[str, int], image_len: int) -> None:
        self.lrw = lrw
        self.image_len = image_len
        self._rows: list[tuple[int, bytes]] = []
        self.on = False
        self._sock = socket.socket(socket.AF_PACKET, socket.SOCK_RAW, 0)
        self._sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 8 << 20)
        self._sock.bind((interface, 0x0003))  # ETH_P_ALL
        self._sock.settimeout(0.2)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def close(self) -> None:
        self._stop.set()
        self._thread.join(2)
        self._sock.close()

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                frame, address = self._sock.recvfrom(2048)
            except TimeoutError:
                continue
            except OSError:
                return
            if not self.on or address[2] == socket.PACKET_OUTGOING or frame[12:14] != ETHERCAT:
                continue
            data = self._lrw_data(frame)
            if data is not None:
                self._rows.append((frame[17] & (CYCLIC_INDICES - 1), data))

    def _lrw_data(self, frame: bytes) -> bytes | None:
        pos = 16  # Ethernet header (14) + EtherCAT header (2)
        while pos + 10 <= len(frame):
            cmd = frame[pos]
            address = struct.unpack_from("<I", frame, pos + 2)[0]
            length = struct.unpack_from("<H", frame, pos + 6)[0]
            more, length = length & 0x8000, length & 0x07FF
            if cmd == LRW and address == self.lrw["address"]:
                return frame[pos + 10 : pos + 10 + length]
            if not more:
                return None
            pos += 10 + length + 2
        return None

    def take(self) -> tuple[npt.NDArray[Any], npt.NDArray[np.uint8]]:
        """(cycle numbers counted from the first reply, images) of what was recorded."""
        rows, self._rows = self._rows, []
        cycles = unwrap([i for i, _ in rows], CYCLIC_INDICES)
        images = np.zeros((len(rows), self.image_len), dtype=np.uint8)
        at = self.lrw["image_offset"]
        for k, (_, data) in enumerate(rows):
            images[k, at : at + len(data)] = np.frombuffer(data, dtype=np.uint8)
        return cycles, images


def unwrap(indices: list[int], modulo: int) -> npt.NDArray[np.int64]:
    """Frame numbers modulo ``modulo`` as counted cycles from the first (each step forward by
    1..modulo−1, or ``modulo`` when the same number comes again: gaps shorter than ``modulo``)."""
    out = np.zeros(len(indices), dtype=np.int64)
    for k in range(1, len(indices)):
        step = (indices[k] - indices[k - 1]) % modulo
        out[k] = out[k - 1] + (step or modulo)
    return out


def fjt_runs(fields: Fields, rounds: int, duration: float) -> list[Run]:
    from ether_ros.ros.rig import RosRig
    from ether_ros.ros.trajectory_client import TrajectoryActionClient, make_goal

    track = trajectory(duration)
    points = [
        (track[JOINTS[0]][i][0], [track[j][i][1] for j in JOINTS])
        for i in range(len(track[JOINTS[0]]))
    ]
    velocities = [[track[j][i][2] for j in JOINTS] for i in range(len(points))]
    runs = []
    with RosRig(CONFIG, netns=True) as rig:
        client = rig.client
        if client.wait_for_node(timeout=60) != "active":
            raise RuntimeError("the node did not come up active")
        # The action client first: the enable below acquires the control lease (where the
        # configuration turns it on, as arm6 does) with the action client already registered.
        fjt = TrajectoryActionClient(client.node)
        ok, message, _ = client.axis_command("enable")
        if not ok:
            raise RuntimeError(f"enable: {message}")
        if client.lease_enabled and not client.lease_token:
            raise RuntimeError("the node's control lease is on but this client does not hold it")
        assert rig.veth is not None
        recorder = WireRecorder(rig.veth.master, fields.lrw, fields.image_len)
        for _ in range(rounds):
            home = fjt.run(JOINTS, [(1.0, [0.0] * 6)])
            if home.status != 4:
                raise RuntimeError(f"going home: {home}")
            time.sleep(0.2)
            recorder.on = True
            time.sleep(0.1)  # cycles before the start are in the recording
            goal = make_goal(JOINTS, points, velocities=velocities, start=time.time() + HOLD)
            outcome = fjt.send(goal).wait(duration + 30)
            time.sleep(0.2)  # the last messages
            recorder.on = False
            if outcome.status != 4:
                raise RuntimeError(f"the FollowJointTrajectory goal did not succeed: {outcome}")
            cycles, images = recorder.take()
            runs.append(analyse(fields, cycles, images, round(duration * 1e9 / fields.cycle_ns)))
        fjt.destroy()
        recorder.close()
    return runs


# ---------------------------------------------------------------------------- report
def _mrad(x: float) -> str:
    return f"{x * 1e3:.2f}"


def run(report: Report) -> None:
    try:
        import ether_ros._native  # noqa: F401
    except ImportError as e:
        raise BenchSkipped(f"ether_ros._native is not built: {e}") from e
    rounds, duration = (1, DURATION) if report.quick else (3, DURATION)
    fields: list[Fields] = []
    api, api_samples = api_runs(fields, rounds, duration)
    fjt = fjt_runs(fields[0], rounds, duration)

    def pooled(runs: list[Run]) -> Tracking:
        return tracking(np.concatenate([r.errors for r in runs]))

    t_api, t_fjt = pooled(api), pooled(fjt)
    report.text("### CiA 402 trajectories: start skew and tracking")
    report.text(
        f"config/arm6.yaml (three simulated two-axis drives, 1 kHz, DC), simulator in a network "
        f"namespace across a veth pair. {rounds} round(s) per path; each a trajectory of "
        f"{len(trajectory(duration)[JOINTS[0]])} points per joint (every {STEP * 1e3:g} ms, "
        f"positions and velocities) over {duration:g} s, ±{AMPLITUDE * 3:g}/k rad (k = 1..3), "
        "for all six joints at once: through the Python API (`bus.follow`, one hand-over) and "
        "through FollowJointTrajectory (the node in its own process, this process the rclpy action "
        "client). Both paths are measured the same way: every cycle's LRW reply, captured on "
        "the master's end of the veth pair, carries the targets sent and the actual positions "
        "of that cycle; the cycles are numbered by the frames' datagram index. The API's start "
        "skew is also read from the engine's own samples (`bus.samples()`), as a cross-check."
    )
    rows = []
    for label, runs in (("Python API (`bus.follow`)", api), ("FollowJointTrajectory", fjt)):
        skews = [r.starts.skew for r in runs]
        inexact = sum(not e for r in runs for e in r.starts.exact)
        gaps = sum(r.gaps for r in runs)
        rows.append([label, " / ".join(map(str, skews)), max(skews), inexact, gaps])
    skews = [s.skew for s in api_samples]
    rows.append(["Python API, from `bus.samples()`", " / ".join(map(str, skews)), max(skews),
                 sum(not e for s in api_samples for e in s.exact), "—"])  # fmt: skip
    report.table(
        [
            "path",
            "start skew per round (cycles)",
            "max skew (cycles)",
            "start cycles not exact (gap before)",
            "cycles missing from the recording",
        ],
        rows,
    )
    rows = []
    for j, name in enumerate(JOINTS):
        rows.append(
            [
                name,
                f"{_mrad(t_api.rms[j])} / {_mrad(t_api.max[j])}",
                f"{_mrad(t_fjt.rms[j])} / {_mrad(t_fjt.max[j])}",
                f"{t_fjt.rms[j] / t_api.rms[j]:.2f} / {t_fjt.max[j] / t_api.max[j]:.2f}",
            ]
        )
    rows.append(
        [
            "**all joints**",
            f"{_mrad(t_api.rms_all)} / {_mrad(t_api.max_all)}",
            f"{_mrad(t_fjt.rms_all)} / {_mrad(t_fjt.max_all)}",
            f"{t_fjt.rms_all / t_api.rms_all:.2f} / {t_fjt.max_all / t_api.max_all:.2f}",
        ]
    )
    report.text(
        "Tracking error: target position sent in a frame − actual position the same frame "
        "brought back, over the trajectory's cycles from the first joint's start, pooled over "
        f"the rounds ({t_api.samples} API and {t_fjt.samples} FJT samples). Target: the same "
        "tracking both ways (ratio 1). Both start the trajectory "
        f"{HOLD * 1e3:g} ms after the call (the FJT goal's header.stamp)."
    )
    report.table(
        [
            "joint",
            "API RMS / max (mrad)",
            "FJT RMS / max (mrad)",
            "FJT / API, RMS / max",
        ],
        rows,
    )
    for key, runs, t in (("api", api, t_api), ("fjt", fjt, t_fjt)):
        report.value(
            key,
            {
                "start_cycles": [r.starts.cycles for r in runs],
                "skew": [r.starts.skew for r in runs],
                "exact": [r.starts.exact for r in runs],
                "gaps": [r.gaps for r in runs],
                "samples_start_cycles": [s.cycles for s in api_samples] if key == "api" else None,
                "rms": t.rms,
                "max": t.max,
                "rms_all": t.rms_all,
                "max_all": t.max_all,
            },
        )
    cycle_ms = fields[0].cycle_ns * 1e-6
    worst = {key: worst_at(runs) for key, runs in (("API", api), ("FJT", fjt))}
    report.text(
        f"99th percentile of |error| over all joints: API {_mrad(t_api.p99_all)} mrad, FJT "
        f"{_mrad(t_fjt.p99_all)} mrad (FJT / API {t_fjt.p99_all / t_api.p99_all:.2f})."
    )
    report.text(
        "Largest error: "
        + "; ".join(
            f"{key} {t.max_all * 1e3:.2f} mrad at {at * cycle_ms:.0f} ms after the start "
            f"({JOINTS[joint]})"
            for (key, (at, joint)), t in zip(worst.items(), (t_api, t_fjt), strict=True)
        )
        + "."
    )
    report.value("ratio_rms", t_fjt.rms_all / t_api.rms_all)
    report.value("ratio_max", t_fjt.max_all / t_api.max_all)
    report.value("ratio_p99", t_fjt.p99_all / t_api.p99_all)
