"""No module of ``python/ether_ros/master`` reads another object's private attributes.

Every attribute access in the package's modules is read with :mod:`ast`: ``x._name`` is allowed
only on ``self`` and ``cls`` (an object's own state); reaching into another object's
underscore attribute — or naming one in ``getattr``/``setattr``/``hasattr`` — fails naming the
module, its line and the expression. What a module needs of another object is that object's
public method or property.
"""

from __future__ import annotations

import ast
from pathlib import Path

MASTER = Path(__file__).resolve().parents[2] / "python" / "ether_ros" / "master"
OWN = {"self", "cls"}


def _private(name: str) -> bool:
    return name.startswith("_") and not (name.startswith("__") and name.endswith("__"))


def reach_ins(source: str, filename: str = "<source>") -> list[tuple[int, str]]:
    """(line, expression) of every read of another object's underscore attribute."""
    found = []
    for node in ast.walk(ast.parse(source, filename)):
        if isinstance(node, ast.Attribute) and _private(node.attr):
            owner = node.value
            if not (isinstance(owner, ast.Name) and owner.id in OWN):
                found.append((node.lineno, ast.unparse(node)))
        elif (
            isinstance(node, ast.Call)
            and isinstance(node.func, ast.Name)
            and node.func.id in ("getattr", "setattr", "hasattr", "delattr")
            and len(node.args) >= 2
            and isinstance(node.args[1], ast.Constant)
            and isinstance(node.args[1].value, str)
            and _private(node.args[1].value)
        ):
            found.append((node.lineno, ast.unparse(node)))
    return found


def test_the_check_sees_a_reach_in() -> None:
    source = (
        "class A:\n"
        "    def f(self, other):\n"
        "        self._mine = other.public\n"
        "        return other._theirs, getattr(other, '_hidden'), cls._ok, self.__class__\n"
    )
    assert reach_ins(source) == [(4, "other._theirs"), (4, "getattr(other, '_hidden')")]


def test_no_master_module_reads_another_objects_private_attributes() -> None:
    modules = sorted(MASTER.glob("*.py"))
    assert len(modules) > 20
    bad = [
        f"{path.relative_to(MASTER.parents[2])}:{line}: {expr}"
        for path in modules
        for line, expr in reach_ins(path.read_text(), str(path))
    ]
    assert not bad, "reads of another object's private attribute:\n" + "\n".join(bad)
