"""Inspection commands as a user runs them: `ether-ros <command>` processes against the
simulator in its own process and network namespace, over a real veth pair."""

from __future__ import annotations

import contextlib
import io
import json
import subprocess
from pathlib import Path
from typing import Any

import pytest

from ether_ros.cli.main import main
from ether_ros.config.esi import load_esi
from user_commands import LAELAPS, REPO, ether_ros

pytestmark = pytest.mark.netns


def cli(*args: str) -> subprocess.CompletedProcess[str]:
    """The same command line through the CLI entry point in this process (no interpreter
    start-up per call; the simulator still answers from its own process over the veth)."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main(list(args))
    return subprocess.CompletedProcess(list(args), code, out.getvalue(), err.getvalue())


def ok_json(*args: str) -> Any:
    out = cli(*args, "--json")
    assert out.returncode == 0, out.stderr
    return json.loads(out.stdout)


def test_states_and_state_requests(sim_iface: str) -> None:
    states = ok_json("states", "-i", sim_iface)
    assert [s["position"] for s in states] == [0, 1, 2, 3]
    assert ok_json("states", "-i", sim_iface, "-p", "2", "PREOP")[0]["state"] == "PREOP"
    assert ok_json("states", "-i", sim_iface, "-p", "2", "INIT")[0]["state"] == "INIT"
    named = ok_json("states", "-i", sim_iface, "-c", str(LAELAPS), "-p", "front_left_leg")
    assert named[0]["position"] == 2 and named[0]["name"] == "front_left_leg"


def test_upload_and_download_by_index_and_by_name(sim_iface: str) -> None:
    vendor = ok_json("upload", "-i", sim_iface, "-p", "0", "0x1018:1")
    assert vendor["value"] == 0x0A12 and vendor["name"] == "Vendor ID"
    cfg = ["-c", str(LAELAPS)]
    ok_json("download", "-i", sim_iface, "-p", "1", "0x7030:3", "4", *cfg)
    got = ok_json("upload", "-i", sim_iface, "-p", "1", "a_ellipse100", *cfg)
    assert (got["index"], got["subindex"], got["value"]) == (0x7030, 3, 4)
    ok_json("download", "-i", sim_iface, "-p", "1", "TrajectoryParameters.a_ellipse100", "0", *cfg)
    assert (
        ok_json("upload", "-i", sim_iface, "-p", "1", "0x7030:03", "--type", "int16")["value"] == 0
    )


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["upload", "-p", "7", "0x1018:1"], "no slave '7' on the bus"),
        (["upload", "-p", "0", "0x9999:1", "--type", "uint8"], "object does not exist"),
        (
            ["download", "-p", "0", "0x7030:3", "70000", "--type", "int16"],
            "70000 is out of range for int16",
        ),
        (["download", "-p", "0", "0x7030:3", "x", "--type", "int16"], "is not a number"),
        (["upload", "-p", "0", "0x7030:3", "--type", "int17"], "unknown data type 'int17'"),
        (["upload", "-p", "0", "no_such_thing", "-c", str(LAELAPS)], "no object 'no_such_thing'"),
        (["states", "-p", "0", "FLYING"], "unknown state 'FLYING'"),
        (["reg-read", "-p", "0", "0xFFFF", "4"], "runs past 0xFFFF"),
        (["reg-write", "-p", "0", "0x1800", "zz"], "is not hex bytes"),
    ],
)
def test_bad_requests_are_one_line_errors(sim_iface: str, args: list[str], message: str) -> None:
    out = cli(*args, "-i", sim_iface)
    assert out.returncode == 2
    assert message in out.stderr and out.stderr.count("\n") == 1, out.stderr


def test_registers(sim_iface: str) -> None:
    # 0x1800: process data RAM no SyncManager covers on this device, free to scribble on.
    al = ok_json("reg-read", "-i", sim_iface, "-p", "0", "0x0130", "--type", "uint16")
    assert al["value"] & 0x0F in (1, 2, 3, 4, 8)
    ok_json("reg-write", "-i", sim_iface, "-p", "3", "0x1800", "a55a")
    assert ok_json("reg-read", "-i", sim_iface, "-p", "3", "0x1800", "2")["hex"] == "a55a"
    ok_json("reg-write", "-i", sim_iface, "-p", "3", "0x1800", "-2", "--type", "int16")
    assert (
        ok_json("reg-read", "-i", sim_iface, "-p", "3", "0x1800", "--type", "int16")["value"] == -2
    )


def test_sii_pdos_and_dictionary(sim_iface: str, tmp_path: Path) -> None:
    sii = ok_json("sii-read", "-i", sim_iface, "-p", "0")
    assert (sii["vendor_id"], sii["product_code"]) == (0x0A12, 0x00A986FD)
    raw = tmp_path / "sii.bin"
    ok_json("sii-read", "-i", sim_iface, "-p", "0", "--raw", "-o", str(raw))
    assert raw.stat().st_size >= 128

    pdos = ok_json("pdos", "-i", sim_iface, "-p", "0")[0]
    assert pdos["source"] == "coe"
    assert [p["index"] for p in pdos["rx_pdos"]] == [0x1600]
    assert sum(e["bit_length"] for e in pdos["rx_pdos"][0]["entries"]) == 38 * 8
    assert sum(e["bit_length"] for e in pdos["tx_pdos"][0]["entries"]) == 22 * 8

    sdos = ok_json("sdos", "-i", sim_iface, "-p", "0")[0]
    assert sdos["source"] == "sdo-info"
    by_index = {o["index"]: o for o in sdos["objects"]}
    traj = by_index[0x7030]
    assert [e["name"] for e in traj["entries"]][1:4] == [
        "x_cntr_traj1000",
        "y_cntr_traj1000",
        "a_ellipse100",
    ]


def test_xml_from_sii_describes_the_same_device(sim_iface: str, tmp_path: Path) -> None:
    out = tmp_path / "leg.xml"
    assert ether_ros("xml", "-i", sim_iface, "-p", "0", "-o", str(out)).returncode == 0
    generated = load_esi(out)[0]
    shipped = load_esi(REPO / "devices" / "laelaps_ii_leg.xml")[0]
    assert (generated.vendor_id, generated.product_code, generated.revision) == (
        shipped.vendor_id,
        shipped.product_code,
        shipped.revision,
    )
    for mine, theirs in zip(
        generated.rx_pdos + generated.tx_pdos, shipped.rx_pdos + shipped.tx_pdos, strict=True
    ):
        assert mine.index == theirs.index
        assert [(e.index, e.subindex, e.bit_length, e.name) for e in mine.entries] == [
            (e.index, e.subindex, e.bit_length, e.name) for e in theirs.entries
        ]
    assert generated.assign_activate == shipped.assign_activate


def test_graph_and_master(sim_iface: str) -> None:
    out = cli("graph", "-i", sim_iface)
    assert out.returncode == 0
    assert "master -> slave0;" in out.stdout
    assert 'slave2 -> slave3 [label="port 1"];' in out.stdout
    topo = ok_json("graph", "-i", sim_iface)
    assert [n["parent"] for n in topo] == [None, 0, 1, 2]
    assert [n["port"] for n in topo] == [0, 1, 1, 1]
    stats = ok_json("master", "-i", sim_iface, "--probes", "10")
    assert stats["slaves"] == 4
    assert stats["round_trip_us"]["probes"] == 10
    assert stats["interface_stats"]["operstate"] in ("up", "unknown")


def test_unknown_interface() -> None:
    out = ether_ros("states", "-i", "nosuch0")
    assert out.returncode == 2 and "nosuch0" in out.stderr and out.stderr.count("\n") == 1
