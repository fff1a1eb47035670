"""Recording files: what goes in comes out, and files that are not ours are refused clearly."""

from __future__ import annotations

import threading
from pathlib import Path
from typing import Any

import pytest

from ether_ros.cli.main import main
from ether_ros.tools.msgdefs import INTERFACE_TEXTS
from ether_ros.tools.recording import (
    TIMING_BATCH,
    BusInfo,
    CycleData,
    CycleTiming,
    JointSpec,
    Recorder,
    RecordingError,
    RecordingWriter,
    SlaveInfo,
    VariableInfo,
    read_recording,
    write_recording,
)

REPO = Path(__file__).resolve().parents[2]


def var(name: str) -> VariableInfo:
    return VariableInfo(name, "int16", 0x6010, 1, 16, -32768, 32767)


BUS = BusInfo(
    "test_bus",
    400,
    (
        SlaveInfo("leg", 0, "LaelapsII_Leg", (var("hip_angle"), var("knee_angle")), (var("a"),)),
        SlaveInfo("io", 1, "GenericIO", (var("in0"),), (), "io_group", 4000),
    ),
)


def cycle(i: int, flags: int = 0) -> CycleData:
    return CycleData(
        CycleTiming(i, 1000 + i * 400_000, 5000 + i, 20_000, 400_000, 110_000, 7, flags, -3),
        inputs={"leg": [100.0 * i, -50.0 * i], "io": [float(i % 2)]} if i % 10 == 0 else {},
        outputs={"leg": [1.0]} if i % 10 == 0 else {},
        raw_in=bytes([i % 256, 1]) if i % 100 == 0 else b"",
        raw_out=b"\x02" if i % 100 == 0 else b"",
        expected_wkc=7,
    )


def test_round_trip(tmp_path: Path) -> None:
    n = 3 * TIMING_BATCH + 17  # several timing batches plus a partial one flushed on close
    path = write_recording(
        tmp_path / "r.mcap",
        BUS,
        (cycle(i, flags=1 if i == 42 else 0) for i in range(n)),
        joints=[JointSpec("hip", "leg", "hip_angle", 0.01)],
    )
    rec = read_recording(path)
    assert rec.bus == BUS
    assert rec.timing["cycle"].tolist() == list(range(n))
    assert rec.timing["wake_latency_ns"][5] == 5005
    assert rec.timing["dc_diff_ns"][0] == -3
    assert rec.lost_frames() == 1
    leg = rec.inputs["leg"]
    assert leg.cycle.tolist() == list(range(0, n, 10))
    assert leg["knee_angle"][3] == -1500.0
    assert rec.outputs["leg"]["a"].tolist() == [1.0] * len(leg.cycle)
    assert rec.joints["position"][:, 0][2] == pytest.approx(20 * 100.0 * 0.01)
    with pytest.raises(RecordingError, match=r"no variable 'nope'.*hip_angle, knee_angle"):
        leg["nope"]
    with pytest.raises(RecordingError, match="no slave 'arm'"):
        rec.bus.slave("arm")


def test_schemas_match_the_ros_interfaces() -> None:
    for name, text in INTERFACE_TEXTS.items():
        path = REPO / "interfaces" / "ether_ros_msgs" / "msg" / f"{name}.msg"
        assert path.read_text() == text, f"{name}: recording schema differs from {path}"


def test_unknown_joint_variable_is_refused(tmp_path: Path) -> None:
    with pytest.raises(RecordingError, match="joint 'hip': slave 'leg' has no input 'thigh'"):
        RecordingWriter(tmp_path / "r.mcap", BUS, joints=[JointSpec("hip", "leg", "thigh")])


def test_recorder_drains_its_source_in_a_thread(tmp_path: Path) -> None:
    class Source:
        def __init__(self) -> None:
            self.next = 0
            self.threads: set[str] = set()

        def cycles(self) -> list[CycleData]:
            self.threads.add(threading.current_thread().name)
            batch = [cycle(i) for i in range(self.next, self.next + 50)]
            self.next += 50
            return batch if self.next <= 500 else []

        def stats(self) -> dict[str, Any]:
            return {"cycles": self.next, "rtt": {"p50": 110000}}

    source = Source()
    writer = RecordingWriter(tmp_path / "r.mcap", BUS)
    recorder = Recorder(source, writer, poll_s=0.001).start()
    while source.next < 550:
        threading.Event().wait(0.01)
    recorder.stop()
    assert source.threads == {"ether_ros-recorder"}
    rec = read_recording(tmp_path / "r.mcap")
    assert rec.timing["cycle"].size == 500
    assert rec.statistics[-1]["rtt.p50"] == "110000"


def test_recorder_reports_a_failing_source(tmp_path: Path) -> None:
    class Broken:
        def cycles(self) -> list[CycleData]:
            raise OSError("ring gone")

        def stats(self) -> dict[str, Any]:
            return {}

    recorder = Recorder(Broken(), RecordingWriter(tmp_path / "r.mcap", BUS)).start()
    with pytest.raises(RecordingError, match="failed: OSError"):
        recorder.stop()


def test_not_ours_truncated_missing(tmp_path: Path) -> None:
    from mcap.writer import Writer

    text = tmp_path / "notes.mcap"
    text.write_text("hello")
    with pytest.raises(RecordingError, match="is not an MCAP recording"):
        read_recording(text)

    foreign = tmp_path / "foreign.mcap"
    with open(foreign, "wb") as fh:
        w = Writer(fh)
        w.start(profile="ros1", library="other")
        w.finish()
    with pytest.raises(RecordingError, match="MCAP file but not an ether_ros recording"):
        read_recording(foreign)

    good = write_recording(tmp_path / "good.mcap", BUS, (cycle(i) for i in range(2000)))
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(good.read_bytes()[: good.stat().st_size // 2])
    with pytest.raises(RecordingError, match="truncated"):
        read_recording(cut)

    with pytest.raises(RecordingError, match="does not exist"):
        read_recording(tmp_path / "missing.mcap")
    with pytest.raises(RecordingError, match="is a directory"):
        read_recording(tmp_path)


def test_plot_command_errors_are_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    bad = tmp_path / "x.mcap"
    bad.write_text("not a recording")
    assert main(["plot", str(bad)]) == 2
    err = capsys.readouterr().err
    assert err.strip() == f"ether-ros plot: error: {bad} is not an MCAP recording"
    good = write_recording(tmp_path / "g.mcap", BUS, (cycle(i) for i in range(50)))
    assert main(["plot", str(good), "--format", "gif"]) == 2
    assert "unknown image format gif" in capsys.readouterr().err


def test_plot_command_writes_timing_figure(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # Only the generic bus here: no leg variables, so only the loop timing figure.
    good = write_recording(tmp_path / "g.mcap", BUS, (cycle(i) for i in range(300)))
    assert main(["plot", str(good), "-o", str(tmp_path / "out"), "--format", "png"]) == 0
    assert capsys.readouterr().out.split() == [str(tmp_path / "out" / "loop_timing.png")]
