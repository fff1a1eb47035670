"""`rt setup` on copies of the fixture trees: dry run, apply, undo."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from ether_ros.cli.main import main
from ether_ros.tools.host import Host
from ether_ros.tools.rt_check import PASS, CheckOptions, run_checks

DATA = Path(__file__).resolve().parent.parent / "data" / "rt"


def snapshot(root: Path) -> dict[str, str]:
    return {str(p.relative_to(root)): p.read_text() for p in sorted(root.rglob("*")) if p.is_file()}


def setup_args(root: Path) -> list[str]:
    """`ether-ros rt setup` on the host tree `root` for RT CPU 3 and NIC enp5s0 (a dry run)."""
    return ["rt", "setup", "--root", str(root), "--cpu", "3", "--interface", "enp5s0"]


def apply_setup(root: Path, undo_file: Path) -> int:
    """`rt setup` applied to `root`, writing the undo record to `undo_file`; the exit code."""
    return main([*setup_args(root), "--apply", "--undo-file", str(undo_file)])


@pytest.fixture
def stock(tmp_path: Path) -> Path:
    root = tmp_path / "host"
    shutil.copytree(DATA / "stock", root)
    return root


def test_dry_run_changes_nothing(stock: Path, capsys: pytest.CaptureFixture[str]) -> None:
    before = snapshot(stock)
    assert main(setup_args(stock)) == 0
    out = capsys.readouterr().out
    assert "would write 3 > /proc/irq/40/smp_affinity_list (now 0-3)" in out
    assert "would write -1 > /proc/sys/kernel/sched_rt_runtime_us" in out
    assert snapshot(stock) == before


def test_apply_then_undo_restores_every_file(stock: Path, tmp_path: Path) -> None:
    before = snapshot(stock)
    undo_file = tmp_path / "undo.json"
    args = setup_args(stock)
    assert main([*args, "--apply", "--undo-file", str(undo_file)]) == 0

    assert (stock / "proc/irq/40/smp_affinity_list").read_text() == "3"
    assert (stock / "proc/irq/50/smp_affinity_list").read_text() == "0-2"
    assert (stock / "proc/irq/default_smp_affinity").read_text() == "7"
    assert (stock / "proc/sys/kernel/sched_rt_runtime_us").read_text() == "-1"
    assert (stock / "sys/devices/system/cpu/cpu3/cpufreq/scaling_governor").read_text() == (
        "performance"
    )
    assert (stock / "sys/devices/system/cpu/cpu2/cpufreq/scaling_governor").read_text() == (
        "powersave\n"
    )  # only the RT CPU
    assert (stock / "sys/devices/system/cpu/cpu3/cpuidle/state3/disable").read_text() == "1"
    assert (stock / "sys/class/net/enp5s0/queues/rx-0/rps_cpus").read_text() == "8"
    assert (stock / "sys/fs/cgroup/ether_ros_rt/cpuset.cpus.partition").read_text() == "isolated"
    assert "cpuset" in (stock / "sys/fs/cgroup/cgroup.subtree_control").read_text()
    assert "rx-usecs: 0" in (stock / "ethtool/enp5s0.coalesce").read_text()
    record = json.loads(undo_file.read_text())
    assert {"path": "/proc/irq/40/smp_affinity_list", "kind": "write", "previous": "0-3"} in (
        record["changes"]
    )

    # The tuned copy now passes the runtime checks setup is responsible for.
    report = run_checks(Host(stock), CheckOptions(interface="enp5s0", cpu=3))
    got = {c.name: c.status for c in report.checks}
    for name in (
        "CPU isolation",
        "CPU frequency governor",
        "CPU idle states",
        "NIC IRQ affinity",
        "RPS/XPS",
        "interrupt coalescing",
        "RT throttling",
    ):
        assert got[name] == PASS, name

    assert main([*args[:4], "--undo", str(undo_file)]) == 0
    after = snapshot(stock)
    # Values come back without the trailing newline the fixture had; compare the content.
    assert {k: v.strip() for k, v in after.items()} == {k: v.strip() for k, v in before.items()}
    assert not (stock / "sys/fs/cgroup/ether_ros_rt").exists()
    assert not undo_file.exists()


def test_refuses_to_leave_no_housekeeping_cpu(
    stock: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    (stock / "sys/devices/system/cpu/isolated").write_text("0-2\n")
    before = snapshot(stock)
    assert apply_setup(stock, undo_file=stock / "u.json") == 2
    assert "no housekeeping CPU" in capsys.readouterr().err
    assert snapshot(stock) == before


def test_unreadable_value_is_left_alone(stock: Path, tmp_path: Path) -> None:
    # A value that cannot be read first could not be restored: setup must not touch it.
    (stock / "proc/sys/kernel/sched_rt_runtime_us").unlink()
    (stock / "proc/sys/kernel/sched_rt_runtime_us").mkdir()
    undo_file = tmp_path / "undo.json"
    assert apply_setup(stock, undo_file=undo_file) == 0
    paths = [c.get("path") for c in json.loads(undo_file.read_text())["changes"]]
    assert "/proc/sys/kernel/sched_rt_runtime_us" not in paths


def test_existing_undo_file_is_not_overwritten(
    stock: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    undo_file = tmp_path / "undo.json"
    undo_file.write_text("{}")
    assert apply_setup(stock, undo_file=undo_file) == 2
    assert "exists" in capsys.readouterr().err


@pytest.mark.parametrize(
    ("content", "message"),
    [
        (None, "does not exist"),
        ("not json", "not readable JSON"),
        ('{"format": "other"}', "not an ether-ros rt setup undo file"),
    ],
)
def test_bad_undo_file(
    stock: Path,
    tmp_path: Path,
    content: str | None,
    message: str,
    capsys: pytest.CaptureFixture[str],
) -> None:
    undo_file = tmp_path / "undo.json"
    if content is not None:
        undo_file.write_text(content)
    assert main(["rt", "setup", "--root", str(stock), "--undo", str(undo_file)]) == 2
    assert message in capsys.readouterr().err


def test_unknown_interface_and_cpu(stock: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["rt", "setup", "--root", str(stock), "--cpu", "3", "--interface", "eth9"]) == 2
    assert "'eth9' not found" in capsys.readouterr().err
    assert main(["rt", "setup", "--root", str(stock), "--cpu", "8", "--interface", "enp5s0"]) == 2
    assert "CPU 8 is not online" in capsys.readouterr().err


def test_irq_threads_go_above_the_rt_thread_and_come_back(tmp_path: Path) -> None:
    root = tmp_path / "host"
    shutil.copytree(DATA / "preempt_rt", root)
    before = snapshot(root)
    undo_file = tmp_path / "undo.json"
    args = setup_args(root)
    # The tuned host's IRQ threads run at 90: above an RT thread at 80, nothing to do there.
    assert main([*args, "--apply", "--undo-file", str(undo_file)]) == 0
    assert "irq/40" not in undo_file.read_text()
    assert main(["rt", "setup", "--root", str(root), "--undo", str(undo_file)]) == 0
    # An RT thread at 92 needs them at 97; enp6s0's IRQ thread is not the EtherCAT NIC's.
    assert main([*args, "--priority", "92", "--apply", "--undo-file", str(undo_file)]) == 0
    stat = (root / "proc/140/stat").read_text().split()
    assert (stat[39], stat[40]) == ("97", "1")  # rt_priority (field 40), policy (field 41)
    assert (root / "proc/150/stat").read_text() == before["proc/150/stat"]
    report = run_checks(Host(root), CheckOptions(interface="enp5s0", cpu=3, priority=92))
    assert {c.name: c.status for c in report.checks}["NIC IRQ thread priority"] == PASS
    assert main(["rt", "setup", "--root", str(root), "--undo", str(undo_file)]) == 0
    assert (root / "proc/140/stat").read_text().split()[39] == "90"
