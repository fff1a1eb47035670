"""What the ROS 2 demo leaves behind: the recording of what its client received and the warning
when the node dropped most of the samples."""

from __future__ import annotations

from pathlib import Path

import pytest

from ether_ros.demo.trot import bus_info, sparse_share
from ether_ros.ros.layout import BusSpec, SlaveSpec, VariableSpec
from ether_ros.tools.recording import RecordingWriter, read_recording

LAYOUT = BusSpec(
    "laelaps",
    400,
    (
        SlaveSpec(
            "front_left_leg",
            2,
            "LaelapsII_Leg",
            (VariableSpec("hip_angle", "INT", 0x6010, 1, 16, -32768, 32767),),
            (VariableSpec("a_ellipse100", "INT", 0x7030, 3, 16, -32768, 32767),),
            "default",
            400,
        ),
    ),
)


def _recording(tmp_path: Path, cycles: list[int]) -> Path:
    path = tmp_path / "demo.mcap"
    with RecordingWriter(path, bus_info(LAYOUT)) as writer:
        for c in cycles:
            writer.write_values(c, {"front_left_leg": [float(c)]}, {"front_left_leg": [5.0]})
    return path


def test_the_layout_becomes_the_recordings_bus(tmp_path: Path) -> None:
    rec = read_recording(_recording(tmp_path, list(range(0, 1000, 10))))
    (slave,) = rec.bus.slaves
    assert (slave.name, slave.position, slave.device) == ("front_left_leg", 2, "LaelapsII_Leg")
    assert [v.name for v in slave.inputs] == ["hip_angle"]
    assert (slave.outputs[0].index, slave.outputs[0].subindex) == (0x7030, 3)
    assert rec.bus.cycle_us == 400
    assert list(rec.inputs["front_left_leg"]["hip_angle"][:3]) == [0.0, 10.0, 20.0]


@pytest.mark.parametrize(
    ("cycles", "missing"),
    [
        (list(range(0, 1000, 10)), 0.0),  # every decimated sample arrived
        ([c for c in range(0, 1000, 10) if c % 40 == 0 or c < 50], 0.71),  # 3 in 4 lost
    ],
)
def test_the_share_of_samples_that_never_arrived(
    tmp_path: Path, cycles: list[int], missing: float
) -> None:
    assert sparse_share(read_recording(_recording(tmp_path, cycles))) == pytest.approx(
        missing, abs=0.01
    )
