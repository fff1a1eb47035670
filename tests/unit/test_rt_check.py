"""`rt check` against the fixture trees in tests/data/rt and against this machine."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from ether_ros.cli.main import main
from ether_ros.tools.host import (
    Host,
    HostError,
    format_cpu_list,
    parse_cpu_list,
    parse_cpu_mask,
    parse_ethtool_coalesce,
)
from ether_ros.tools.rt_check import FAIL, PASS, SKIP, WARN, CheckOptions, run_checks

DATA = Path(__file__).resolve().parent.parent / "data" / "rt"


def statuses(root: Path, **kw: object) -> dict[str, str]:
    report = run_checks(Host(root), CheckOptions(**kw))  # type: ignore[arg-type]
    return {c.name: c.status for c in report.checks}


def test_cpu_list_and_mask_round_trip() -> None:
    assert parse_cpu_list("0-2,5") == {0, 1, 2, 5}
    assert format_cpu_list({0, 1, 2, 5, 7, 8}) == "0-2,5,7-8"
    assert parse_cpu_mask("00000000,0000000c") == {2, 3}
    with pytest.raises(HostError, match="not a CPU list"):
        parse_cpu_list("zero")


def test_tuned_preempt_rt_host_passes_everything() -> None:
    got = statuses(DATA / "preempt_rt", interface="enp5s0", cpu=3)
    assert set(got.values()) == {PASS}, got
    assert len(got) == 15


def test_stock_host_fails_on_kernel_and_privileges_and_warns_on_the_rest() -> None:
    got = statuses(DATA / "stock", interface="enp5s0", cpu=3)
    assert got["preemption model"] == FAIL
    assert got["capabilities"] == FAIL
    assert got["locked memory limit"] == FAIL
    for name in (
        "CPU isolation",
        "CPU frequency governor",
        "CPU idle states",
        "irqbalance",
        "NIC IRQ affinity",
        "NIC IRQ thread priority",
        "RPS/XPS",
        "interrupt coalescing",
        "RT throttling",
    ):
        assert got[name] == WARN, name


def test_every_non_pass_row_says_how_to_fix_it() -> None:
    report = run_checks(Host(DATA / "stock"), CheckOptions(interface="enp5s0", cpu=3))
    for check in report.checks:
        if check.status in (WARN, FAIL):
            assert check.fix, check.name


def test_other_cpu_is_not_isolated_on_the_tuned_host() -> None:
    got = statuses(DATA / "preempt_rt", interface="enp5s0", cpu=1)
    assert got["CPU isolation"] == WARN
    assert got["NIC IRQ affinity"] == WARN  # the NIC's IRQs are on CPU 3, not 1


def test_irq_thread_below_the_rt_thread_is_flagged(tmp_path: Path) -> None:
    root = tmp_path / "host"
    shutil.copytree(DATA / "preempt_rt", root)
    assert statuses(root, interface="enp5s0", cpu=3, priority=95)["NIC IRQ thread priority"] == WARN


def test_isolated_cgroup_partition_counts_as_isolation(tmp_path: Path) -> None:
    root = tmp_path / "host"
    shutil.copytree(DATA / "stock", root)
    part = root / "sys/fs/cgroup/ether_ros_rt"
    part.mkdir()
    (part / "cpuset.cpus").write_text("2\n")
    (part / "cpuset.cpus.partition").write_text("isolated\n")
    assert statuses(root, cpu=2)["CPU isolation"] == PASS
    assert statuses(root, cpu=3)["CPU isolation"] == WARN


def test_isolating_every_cpu_fails(tmp_path: Path) -> None:
    root = tmp_path / "host"
    shutil.copytree(DATA / "preempt_rt", root)
    (root / "sys/devices/system/cpu/isolated").write_text("0-3\n")
    assert statuses(root, cpu=3)["CPU isolation"] == FAIL


def test_interface_checks_skip_without_interface() -> None:
    got = statuses(DATA / "stock", cpu=3)
    assert got["NIC IRQ affinity"] == SKIP
    assert got["interrupt coalescing"] == SKIP


def test_ethtool_output_is_parsed() -> None:
    text = "Coalesce parameters for eth0:\nAdaptive RX: on  TX: off\nrx-usecs: 3\nrx-frames: 0\n"
    assert parse_ethtool_coalesce(text).values == {
        "adaptive-rx": "on",
        "adaptive-tx": "off",
        "rx-usecs": "3",
        "rx-frames": "0",
    }


def test_cli_json_and_exit_codes(capsys: pytest.CaptureFixture[str]) -> None:
    assert (
        main(
            [
                "rt",
                "check",
                "--root",
                str(DATA / "preempt_rt"),
                "--interface",
                "enp5s0",
                "--cpu",
                "3",
                "--json",
            ]
        )
        == 0
    )
    data = json.loads(capsys.readouterr().out)
    assert data["result"] == PASS and len(data["checks"]) == 15
    assert main(["rt", "check", "--root", str(DATA / "stock"), "--cpu", "3"]) == 1
    assert "FAIL  preemption model" in capsys.readouterr().out


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--root", "/no/such/host"], "does not exist"),
        (["--root", str(DATA / "stock"), "--cpu", "9"], "CPU 9 is not online"),
        (["--root", str(DATA / "stock"), "--interface", "eth7"], "'eth7' not found"),
    ],
)
def test_bad_input_is_one_line_error(
    args: list[str], message: str, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["rt", "check", *args]) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1


def test_runs_on_this_machine() -> None:
    report = run_checks(Host("/"), CheckOptions(cpu=0))
    assert len(report.checks) == 15
    assert all(c.status in (PASS, WARN, FAIL, SKIP) for c in report.checks)


def test_cpu_dma_latency_holder_covers_deep_idle_states(tmp_path: Path) -> None:
    root = tmp_path / "host"
    shutil.copytree(DATA / "stock", root)
    assert statuses(root, cpu=3)["CPU idle states"] == WARN
    fd_dir = root / "proc/900/fd"
    fd_dir.mkdir(parents=True)
    (fd_dir / "3").symlink_to("/dev/cpu_dma_latency")
    report = run_checks(Host(root), CheckOptions(cpu=3))
    row = next(c for c in report.checks if c.name == "CPU idle states")
    assert row.status == PASS and "pid 900" in row.found
