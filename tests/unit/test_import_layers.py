"""The import graph of ``python/ether_ros`` keeps to the layers of docs/architecture.md.

Every ``import`` in the package (at any depth: a function-level or ``TYPE_CHECKING`` import is an
arrow too) is read with :mod:`ast` and checked against :data:`MAY_IMPORT`, the arrows allowed
between the package's top-level parts. The arrows point down only, so the parts have no cycle;
a wrong arrow fails naming the module, its line and what it imports.
"""

from __future__ import annotations

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[2] / "python" / "ether_ros"

# What each top-level part may import directly (besides itself); anything below that is allowed
# too (the closure). Top → bottom: cli and demo / console / ros / tools → master and sim beside
# it → config → the leaves (errors, protocol). ``testing`` serves tests and benchmarks only.
MAY_IMPORT: dict[str, set[str]] = {
    "ether_ros": set(),  # the package itself: its __version__, nothing else
    "_native": set(),  # the extension (protocol, engine, simulator)
    "laelaps": set(),  # the Laelaps II trot table (thesis Table 6.1): experiments, proof, demo
    "errors": {"_native"},
    "topology": {"_native", "errors"},
    "netns": {"errors"},
    "claim": {"errors"},
    "config": {"_native", "errors", "topology"},
    "master": {"ether_ros", "config", "claim"},
    "sim": {"config", "claim", "netns", "laelaps"},
    "tools": {"ether_ros", "master", "sim"},
    "ros": {"ether_ros", "tools"},
    "console": {"ether_ros", "ros"},
    "demo": {"console"},
    "cli": {"demo", "console"},
    "testing": {"cli"},
}


def closure(graph: dict[str, set[str]]) -> dict[str, set[str]]:
    """Everything each part may reach, refusing a cycle in the rules themselves."""
    out: dict[str, set[str]] = {}

    def reach(part: str, path: tuple[str, ...]) -> set[str]:
        assert part not in path, f"the allowed arrows have a cycle: {' -> '.join((*path, part))}"
        if part not in out:
            below: set[str] = set()
            for lower in graph[part]:
                below |= {lower} | reach(lower, (*path, part))
            out[part] = below
        return out[part]

    for part in graph:
        reach(part, ())
    return out


def module_name(path: Path) -> str:
    parts = list(path.relative_to(PACKAGE.parent).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def part_of(module: str) -> str:
    """``ether_ros.master.bus`` → ``master``; ``ether_ros`` → ``ether_ros``."""
    names = module.split(".")
    return names[1] if len(names) > 1 else names[0]


def imports(path: Path) -> list[tuple[int, str]]:
    """(line, absolute module) of every ether_ros import in ``path``."""
    module = module_name(path)
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    found = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            names = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[: len(package.split(".")) - node.level + 1]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            # ``from ether_ros import tools`` imports the part ``tools``.
            names = [f"{target}.{a.name}" if target == "ether_ros" else target for a in node.names]
        else:
            continue
        found += [(node.lineno, n) for n in names if n == "ether_ros" or n.startswith("ether_ros.")]
    return found


def wrong_arrows() -> list[str]:
    allowed = closure(MAY_IMPORT)
    wrong = []
    for path in sorted(PACKAGE.rglob("*.py")):
        source = module_name(path)
        here = part_of(source)
        for line, target in imports(path):
            there = part_of(target)
            if target == "ether_ros.__version__":
                there = "ether_ros"
            if there == here:
                continue
            if here not in allowed:
                wrong.append(f"{source}: a part the layers do not know ({here}); add it")
            elif there not in allowed:
                wrong.append(f"{source}:{line} imports {target}: a part the layers do not know")
            elif there not in allowed[here]:
                wrong.append(f"{source}:{line} imports {target}: {here} may not import {there}")
    return sorted(set(wrong))


def test_every_arrow_points_down() -> None:
    wrong = wrong_arrows()
    assert not wrong, "imports against the layers (docs/architecture.md):\n" + "\n".join(wrong)


def test_every_part_has_its_place() -> None:
    parts = {part_of(module_name(p)) for p in PACKAGE.rglob("*.py")} | {"_native"}
    assert parts == set(MAY_IMPORT), f"parts without a layer: {sorted(parts - set(MAY_IMPORT))}"


def test_product_code_never_imports_testing() -> None:
    allowed = closure(MAY_IMPORT)
    assert [part for part, below in allowed.items() if "testing" in below] == []


def test_the_check_sees_a_wrong_arrow(tmp_path: Path) -> None:
    """The parser finds relative, absolute and function-level imports (a check that saw none
    would pass anything)."""
    mod = tmp_path / "ether_ros" / "sim" / "x.py"
    mod.parent.mkdir(parents=True)
    mod.write_text(
        "from ..tools import live\nimport ether_ros.testing.netns\n"
        "def f():\n    from ether_ros import console\n"
    )
    global PACKAGE
    saved, PACKAGE = PACKAGE, tmp_path / "ether_ros"
    try:
        found = imports(mod)
    finally:
        PACKAGE = saved
    assert [t for _, t in found] == [
        "ether_ros.tools",
        "ether_ros.testing.netns",
        "ether_ros.console",
    ]
    allowed = closure(MAY_IMPORT)
    assert {"tools", "testing", "console"}.isdisjoint(allowed["sim"])
