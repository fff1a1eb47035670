"""The docs run as written: every shell and Python example of README.md and docs/*.md runs on
the simulator (a veth pair, ``ether-ros sim`` in its own network namespace, the real engine and,
where the example starts one, the real ROS 2 node), with the docs' interface names replaced by
the test's (``ether_ros.testing.docs``). Examples that cannot run here carry
``<!-- not-run: REASON -->`` and are listed by ``test_not_run_examples_are_listed``.

How a shell example runs: in bash with ``set -e``, in a scratch directory that links the
repository's config/, devices/, tests/, docs/ and .venv; ``ether-ros`` is a function that runs
the CLI of this checkout. ``ether-ros sim`` runs in the simulator's namespace and returns once it
is ready; ``ether-ros run`` (the node) returns once it is up; both keep running until the example
ends, when the whole process group gets SIGTERM (the node deactivates: safe outputs, SAFEOP).
``ip link ...`` lines (making the veth pair) are the test's own pair. ``rt check`` may exit 1 (a
failed check on this host is an answer, not an error). A shell example without its own
``ether-ros sim`` gets the test's simulator. An example marked ``<!-- docs-expect: REGEX -->``
must also print what matches REGEX (its result code, what it claims).
"""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import tempfile
from collections.abc import Iterator
from contextlib import ExitStack, contextmanager
from pathlib import Path

import pytest

from ether_ros.sim.proof import SimProcess
from ether_ros.testing.docs import DEFAULT_SIM, Block, blocks, doc_files, substitute
from ether_ros.testing.netns import VethPair
from ether_ros.testing.wait import wait_for

pytestmark = pytest.mark.netns

REPO = Path(__file__).resolve().parents[2]
LINKED = ("config", "devices", "tests", "docs", "scripts", ".venv", "README.md")
TIMEOUT_S = 600  # stops a hung example only; no example is timed

ALL = [b for path in doc_files(REPO) for b in blocks(path)]
RUNNABLE = [b for b in ALL if b.not_run is None]

PRELUDE = r"""
set -e
_docs_wait() {  # PID LOG TEXT: until TEXT is in LOG (the process still running)
  for _ in $(seq 3000); do
    grep -q "$3" "$2" && return 0
    kill -0 "$1" 2>/dev/null || { cat "$2" >&2; return 1; }
    sleep 0.1
  done
  cat "$2" >&2; return 1
}
ether-ros() {
  case "$1" in
    sim) ip netns exec "$DOCS_NETNS" "$DOCS_PY" -m ether_ros.cli.main "$@" \
           > "$DOCS_TMP/sim.log" 2>&1 &
         _docs_wait $! "$DOCS_TMP/sim.log" ready ;;
    run) "$DOCS_PY" -m ether_ros.cli.main "$@" > "$DOCS_TMP/run.log" 2>&1 &
         _docs_wait $! "$DOCS_TMP/run.log" "ether-ros run:" ;;
    rt) local rc=0; "$DOCS_PY" -m ether_ros.cli.main "$@" || rc=$?; [ "$rc" -le 1 ] ;;
    *) "$DOCS_PY" -m ether_ros.cli.main "$@" ;;
  esac
}
"""

# `ether-ros sim ... &` / `ether-ros run ... &`: the function backgrounds them itself, after
# waiting for them to be ready, so the next line finds them running.
_SERVER_IN_BACKGROUND = re.compile(r"^(\s*ether-ros\s+(?:sim|run)\b[^&#\n]*?)\s*&(?!&)", re.M)
_IP_LINK = re.compile(r"^(\s*)(ip link .*)$", re.M)


def shell_script(text: str) -> str:
    text = _SERVER_IN_BACKGROUND.sub(r"\1", text)
    text = _IP_LINK.sub(r"\1# the test's own veth pair instead of: \2", text)
    return PRELUDE + text


@pytest.fixture(scope="module")
def scratches() -> Iterator[dict[Path, Path]]:
    """One scratch directory per markdown file: its examples run in order in it, so a file an
    example writes (``trot.mcap``) is there for the next example of the same page."""
    made: dict[Path, Path] = {}
    with tempfile.TemporaryDirectory(prefix="ether-ros-docs-") as root:
        for path in doc_files(REPO):
            tmp = Path(root) / path.stem
            tmp.mkdir()
            for name in LINKED:
                if (REPO / name).exists():
                    os.symlink(REPO / name, tmp / name)
            made[path] = tmp
        yield made


@contextmanager
def node(config: Path, interface: str, log: Path) -> Iterator[None]:
    """``ether-ros run CONFIG -i INTERFACE`` for an example that talks to the node over ROS 2;
    SIGTERM afterwards (it deactivates: safe outputs, SAFEOP)."""
    with open(log, "wb") as out:
        proc = subprocess.Popen(
            [sys.executable, "-m", "ether_ros.cli.main", "run", str(config), "-i", interface],
            stdout=out,
            stderr=subprocess.STDOUT,
            env={**os.environ, "PYTHONUNBUFFERED": "1"},
        )
    try:
        wait_for(
            "the node to start",
            lambda: proc.poll() is not None or b"ether-ros run:" in log.read_bytes(),
            120,
        )
        assert proc.poll() is None, f"the node ended: {log.read_text(errors='replace')}"
        yield
    finally:
        proc.terminate()
        try:
            proc.wait(30)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


def _sim_args(block: Block) -> tuple[Path | None, list[str]]:
    """The simulated bus of an example (``docs-test: sim=...`` or ``esi=... device=...``)."""
    if "esi" in block.options:
        extra = ["--esi", str(REPO / block.options["esi"])]
        if "device" in block.options:
            extra += ["--device", block.options["device"]]
        extra += ["--count", block.options.get("count", "1")]
        return None, extra
    return REPO / block.options.get("sim", DEFAULT_SIM), []


def _python_source(block: Block) -> str:
    """The block, after the file's previous Python block when it says it continues it."""
    if "continues" not in block.options:
        return block.text
    earlier = [
        b for b in ALL if b.path == block.path and b.lang == "python" and b.line < block.line
    ]
    assert earlier, f"{block.where}: 'continues' but no Python block before it"
    return _python_source(earlier[-1]) + block.text


def _stop_group(proc: subprocess.Popen[bytes]) -> None:
    """SIGTERM to everything the example started (the node deactivates), SIGKILL if it hangs."""
    for sig, grace in ((signal.SIGTERM, 30.0), (signal.SIGKILL, 10.0)):
        try:
            os.killpg(proc.pid, sig)
        except ProcessLookupError:
            return
        try:
            wait_for("the example's processes to end", lambda: _group_gone(proc), grace)
            return
        except AssertionError:  # still there: escalate to SIGKILL
            continue


def _group_gone(proc: subprocess.Popen[bytes]) -> bool:
    proc.poll()  # reap the example's shell itself (a zombie still counts as a member)
    try:
        os.killpg(proc.pid, 0)
    except ProcessLookupError:
        return True
    return False


def _report(block: Block, what: str, out: bytes, err: bytes, code: int | None) -> str:
    tail = lambda b: "\n".join(b.decode(errors="replace").splitlines()[-25:])  # noqa: E731
    return (
        f"{block.path.relative_to(REPO)}:{block.line}: the {block.lang} example {what} "
        f"(exit {code}). Fix the example, or mark it <!-- not-run: REASON --> if it cannot "
        f"run on the simulator.\n--- example ---\n{block.text}--- stdout ---\n{tail(out)}\n"
        f"--- stderr ---\n{tail(err)}"
    )


def run_example(block: Block, scratches: dict[Path, Path]) -> None:
    scratch = scratches[block.path]
    starts_sim = block.lang == "sh" and re.search(r"^\s*ether-ros\s+sim\b", block.text, re.M)
    with VethPair.create(netns=True) as veth, ExitStack() as stack:
        config, extra = _sim_args(block)
        sim = (
            None
            if starts_sim or block.options.get("sim") == "none"
            else SimProcess(config, veth.slave, veth.netns, extra=extra)
        )
        if sim is not None:
            sim.start()
            stack.callback(sim.stop)
        if "node" in block.options:
            assert config is not None, f"{block.where}: a node needs a bus configuration"
            stack.enter_context(node(config, veth.master, scratch / "node.log"))
        env = {
            **os.environ,
            "DOCS_PY": sys.executable,
            "DOCS_NETNS": veth.netns or "",
            "DOCS_TMP": str(scratch),
            "PYTHONUNBUFFERED": "1",
            "PYTHONPATH": str(REPO / "tests"),
        }
        if block.lang == "sh":
            text = substitute(block.text, veth.master, veth.slave, cpu=(os.cpu_count() or 1) - 1)
            argv = ["bash", "-c", shell_script(text)]
        else:
            argv = [sys.executable, "-c", substitute(_python_source(block), veth.master,
                                                     veth.slave)]  # fmt: skip
        proc = subprocess.Popen(
            argv,
            cwd=scratch,
            env=env,
            stdin=subprocess.DEVNULL,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            start_new_session=True,
        )
        try:
            out, err = proc.communicate(timeout=TIMEOUT_S)
        except subprocess.TimeoutExpired:
            _stop_group(proc)
            out, err = proc.communicate()
            pytest.fail(_report(block, "hung", out, err, None))
        finally:
            _stop_group(proc)
        assert proc.returncode == 0, _report(block, "failed", out, err, proc.returncode)
        text = (out + err).decode(errors="replace")
        assert "Traceback" not in text, _report(block, "printed a traceback", out, err, 0)
        if block.expect is not None:  # what it prints is what it claims (a result code)
            printed = out.decode(errors="replace")
            assert re.search(block.expect, printed, re.M), _report(
                block, f"did not print what it claims (/{block.expect}/)", out, err, 0
            )


def _examples_of(path: Path) -> type:
    """The class of one page's examples. A class per page, because the tests run on several
    workers a scope (a module, or a class) at a time (``--dist loadscope``): the pages run side
    by side while each page's examples still run in order on one worker, in one scratch
    directory (an example may use the file the one before it wrote)."""
    page = [b for b in RUNNABLE if b.path == path]

    @pytest.mark.timeout(TIMEOUT_S + 120)  # the trot and its figures are slow on a loaded host
    @pytest.mark.parametrize("block", page, ids=[b.where for b in page])
    def test_example_runs(self: object, block: Block, scratches: dict[Path, Path]) -> None:
        run_example(block, scratches)

    name = "TestExamplesOf" + "".join(w.capitalize() for w in re.split(r"[^A-Za-z0-9]+", path.stem))
    return type(name, (), {"test_example_runs": test_example_runs, "__doc__": f"{path.name}"})


for _page in sorted({b.path for b in RUNNABLE}):
    _cls = _examples_of(_page)
    globals()[_cls.__name__] = _cls


def test_not_run_examples_are_listed(capsys: pytest.CaptureFixture[str]) -> None:
    """Every example the test does not run says why, and the list is printed."""
    skipped = [b for b in ALL if b.not_run is not None]
    with capsys.disabled():
        print(f"\n{len(RUNNABLE)} examples run; {len(skipped)} not run:")
        for b in skipped:
            print(f"  {b.path.relative_to(REPO)}:{b.line}: {b.not_run}")
    for b in skipped:
        assert len(b.not_run or "") >= 8, f"{b.where}: say why it cannot run"
    assert RUNNABLE, "no example runs"
