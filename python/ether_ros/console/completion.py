"""Tab completion for the console: commands, slave names and variable names from the layout the
node published. Pure (no ROS): it reads the current :class:`ConsoleContext` through a callable."""

from __future__ import annotations

import shlex
from collections.abc import Callable, Iterable, Iterator

from prompt_toolkit.completion import CompleteEvent, Completer, Completion
from prompt_toolkit.document import Document

from ether_ros.config.cia402 import MODES
from ether_ros.console.commands import HELP, ConsoleContext
from ether_ros.ros.layout import LayoutError

COMMANDS = sorted({*HELP, "clear", "exit"})
SDO_TYPES = ["bool", "int8", "int16", "int32", "int64", "uint8", "uint16", "uint32", "uint64",
             "real32", "real64"]  # fmt: skip


def candidates(words: list[str], ctx: ConsoleContext) -> list[str]:
    """What may come next after ``words`` (the complete words before the cursor)."""
    if not words:
        return COMMANDS
    head = words[0].lower()
    slaves = [s.name for s in ctx.layout.slaves] if ctx.layout is not None else []
    n = len(words)
    if head == "help" and n == 1:
        return sorted(HELP)
    if head in ("get", "layout") and n == 1:
        return slaves
    if head == "set":
        if n == 1:
            return ["all", *slaves]
        return [f"{name}=" for name in _outputs(ctx, words[1])]
    if head == "get" and n == 2:
        return _outputs(ctx, words[1]) + _inputs(ctx, words[1])
    if head == "sdo":
        if n == 1:
            return ["read", "write"]
        if n == 2:
            return slaves
        if n == 4:
            return SDO_TYPES
    if head == "run" and n == 2:
        return ["step"]
    joints = list(ctx.joints)
    if head in ("enable", "disable", "reset_fault"):
        return ["all", *joints] if n == 1 else joints
    if head == "set_mode":
        return ["all", *joints] if n == 1 else list(MODES) if n == 2 else []
    if head == "move" and n == 1:
        return joints
    return []


def _outputs(ctx: ConsoleContext, target: str) -> list[str]:
    if ctx.layout is None:
        return []
    if target.lower() == "all":
        names: dict[str, None] = {}
        for s in ctx.layout.slaves:
            names.update(dict.fromkeys(v.name for v in s.outputs))
        return list(names)
    try:
        return [v.name for v in ctx.layout.slave(target).outputs]
    except LayoutError:
        return []


def _inputs(ctx: ConsoleContext, target: str) -> list[str]:
    if ctx.layout is None:
        return []
    try:
        return [v.name for v in ctx.layout.slave(target).inputs]
    except LayoutError:
        return []


def complete(text: str, ctx: ConsoleContext) -> list[str]:
    """Completions of the last (partial) word of ``text``."""
    try:
        words = shlex.split(text)
    except ValueError:
        return []
    partial = "" if not text or text[-1].isspace() else (words.pop() if words else "")
    return [c for c in candidates(words, ctx) if c.startswith(partial)]


class ConsoleCompleter(Completer):
    def __init__(self, context: Callable[[], ConsoleContext]) -> None:
        self._context = context

    def get_completions(
        self, document: Document, complete_event: CompleteEvent
    ) -> Iterator[Completion]:
        text = document.text_before_cursor
        partial = "" if not text or text[-1].isspace() else text.split()[-1]
        for c in _unique(complete(text, self._context())):
            yield Completion(c, start_position=-len(partial))


def _unique(items: Iterable[str]) -> Iterator[str]:
    seen: set[str] = set()
    for i in items:
        if i not in seen:
            seen.add(i)
            yield i
