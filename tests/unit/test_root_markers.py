"""Every test that needs root carries the ``netns`` marker, so ``pytest -m "not netns"`` runs
what an unprivileged user can and nothing in it fails for want of privileges.

A test needs root when its code, or a fixture or module-level helper it reaches by name, uses
a facility only root (or CAP_NET_RAW / CAP_NET_ADMIN / CAP_SYS_NICE / CAP_IPC_LOCK) has: veth
pairs and network namespaces, raw AF_PACKET sockets and the links built on them, SCHED_FIFO
threads, locked memory, switching user — or when it starts a bus (in process too) on a shipped
configuration, whose ``realtime`` section asks for SCHED_FIFO, a pinned CPU and locked memory,
in a module that never turns those off. It is marked when its module's ``pytestmark``, its own
decorator or a fixture of ``ROOT_FIXTURES`` (auto-marked by tests/conftest.py) says so.
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

TESTS = Path(__file__).resolve().parents[1]

#: Code (comments and docstrings left out) that only root may run. Opening an interface named
#: by a literal is a test of the error for a missing one, which an unprivileged user gets too.
ROOT_ONLY = re.compile(
    r"VethPair\.create\(|\bAF_PACKET\b|\bSOCK_RAW\b|\.open_interface\((?!')|\.run_on_interface\((?!')"
    r"|\bthread_in_netns\(|\bnetns_command\(|\bsched_setscheduler\(|\bmlockall\("
    r"|\bunshare\(|\bRosRig\(|\bSimProcess\(|'netns'|\bsetres[ug]id\(|\bset[ug]id\("
    r"|SCHED_FIFO \d|'policy': 'fifo'|\bgeteuid\(\) != 0|\bsu\b.*nobody"
)
#: Starting a bus's cyclic exchange: its RT thread takes the configuration's realtime policy.
STARTS_A_BUS = re.compile(
    r"\bbus\.start\(\)|\.start_cyclic\(|command\('(start|activate|restart)'\)"
)
#: A module that turns the realtime policy off for its buses (then starting one needs no root).
NO_REALTIME = re.compile(
    r"policy = 'other'|'policy': 'other'|policy: other|lock_memory = False|'lock_memory': False"
)


def _helper_without_realtime(node: ast.Import | ast.ImportFrom) -> bool:
    """The import names a module of tests/ (not a package) that turns the realtime policy off."""
    names = [a.name for a in node.names] if isinstance(node, ast.Import) else [node.module or ""]
    for name in names:
        helper = TESTS / f"{name}.py"
        if helper.is_file() and NO_REALTIME.search(ast.unparse(ast.parse(helper.read_text()))):
            return True
    return False


def root_fixtures() -> frozenset[str]:
    tree = ast.parse((TESTS / "conftest.py").read_text())
    for node in tree.body:
        if isinstance(node, ast.Assign) and any(
            isinstance(t, ast.Name) and t.id == "ROOT_FIXTURES" for t in node.targets
        ):
            call = node.value
            assert isinstance(call, ast.Call)
            return frozenset(ast.literal_eval(call.args[0]))
    raise AssertionError("tests/conftest.py has no ROOT_FIXTURES")


def _without_docstring(fn: ast.FunctionDef | ast.AsyncFunctionDef) -> str:
    body = fn.body
    if body and isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant):
        body = body[1:]
    return "\n".join(ast.unparse(stmt) for stmt in body)


def _marks_netns(decorators: list[ast.expr]) -> bool:
    return any("mark.netns" in ast.unparse(d) for d in decorators)


def _module_marked(tree: ast.Module) -> bool:
    for node in tree.body:
        if isinstance(node, ast.Assign) and any(
            isinstance(t, ast.Name) and t.id == "pytestmark" for t in node.targets
        ):
            return "mark.netns" in ast.unparse(node.value)
    return False


def unmarked_root_tests(path: Path, roots: frozenset[str]) -> list[str]:
    tree = ast.parse(path.read_text(), str(path))
    if _module_marked(tree):
        return []
    plain_rt = bool(NO_REALTIME.search(ast.unparse(tree))) or any(
        # A shared test helper that makes the plans (tests/engine_plans.py) counts as the
        # module's own code for the realtime policy.
        isinstance(n, ast.Import | ast.ImportFrom) and _helper_without_realtime(n)
        for n in tree.body
    )
    # Module-level functions (tests, fixtures, helpers) and classes (rigs): what a test reaches.
    functions = {
        n.name: n
        for n in tree.body
        if isinstance(n, ast.FunctionDef | ast.AsyncFunctionDef | ast.ClassDef)
    }

    def reaches(fn: ast.FunctionDef | ast.AsyncFunctionDef) -> tuple[bool, bool]:
        """(needs root, marked by a root fixture or decorator) for ``fn`` and what it reaches."""
        seen: set[str] = set()
        todo: list[ast.FunctionDef | ast.AsyncFunctionDef | ast.ClassDef] = [fn]
        needs = False
        marked = _marks_netns(fn.decorator_list)
        while todo:
            f = todo.pop()
            if f.name in seen:
                continue
            seen.add(f.name)
            code = ast.unparse(f) if isinstance(f, ast.ClassDef) else _without_docstring(f)
            needs = needs or bool(ROOT_ONLY.search(code))
            needs = needs or (not plain_rt and bool(STARTS_A_BUS.search(code)))
            if isinstance(f, ast.ClassDef):
                params: list[str] = []
            else:
                params = [a.arg for a in f.args.args + f.args.kwonlyargs]
            marked = marked or bool(roots & set(params))
            names = {n.id for n in ast.walk(f) if isinstance(n, ast.Name)} | set(params)
            todo += [functions[n] for n in names if n in functions]
        return needs, marked

    out = []
    for name, fn in functions.items():
        if not name.startswith("test_"):
            continue
        needs, marked = reaches(fn)
        if needs and not marked:
            out.append(f"{path.relative_to(TESTS.parent)}::{name}")
    return out


def test_every_test_that_needs_root_is_marked() -> None:
    roots = root_fixtures()
    missing = [t for p in sorted(TESTS.rglob("test_*.py")) for t in unmarked_root_tests(p, roots)]
    assert not missing, "tests that need root without the netns marker:\n" + "\n".join(missing)


def test_the_check_sees_an_unmarked_root_test(tmp_path: Path) -> None:
    """A raw socket reached through a helper and a fixture is found; the same test with the
    marker, or through a root fixture, is not."""
    af, raw_type = "AF" + "_PACKET", "SOCK" + "_RAW"
    raw = f"socket.socket(socket.{af}, socket.{raw_type}, 0)"
    mod = tmp_path / "test_x.py"  # the facility's name split: this module is checked too
    mod.write_text(
        "import socket, pytest\n"
        f"def helper():\n    return {raw}\n"
        "@pytest.fixture\ndef sock():\n    return helper()\n"
        "def test_unmarked(sock):\n    pass\n"
        "@pytest.mark.netns\ndef test_marked(sock):\n    pass\n"
        "def test_through_veth(veth, sock):\n    pass\n"
        "def test_plain():\n    pass\n"
    )
    assert [t.rsplit("::", 1)[1] for t in _unmarked(mod)] == ["test_unmarked"]


def _unmarked(path: Path) -> list[str]:
    global TESTS
    saved, TESTS = TESTS, path.parent
    try:
        return unmarked_root_tests(path, frozenset({"veth"}))
    finally:
        TESTS = saved
