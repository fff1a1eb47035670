"""Sequence files: a list of console steps (writes, waits, control commands) run in order.

A sequence is YAML::

    description: Trot of thesis Table 6.1
    steps:
      - set: {target: all, values: {b_ellipse100: 4}}     # mapping form
      - wait: 3
      - set all a_ellipse100=5                            # a console line
      - panic

Each step is either a console command line or a one-key mapping (``set``, ``wait``, or a control
command with a null value). The whole file is checked before the first step runs, each write
against the state the earlier steps leave, so a bad step 7 stops the run before step 1 is sent.
Only ``set``, ``wait``, ``sdo write`` and the control commands are allowed: a sequence cannot run
another sequence, and never anything outside the console's command language.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ether_ros.config.yamlsrc import load_yaml
from ether_ros.console.commands import (
    Command,
    CommandError,
    ConsoleContext,
    Control,
    SdoWrite,
    Wait,
    Write,
    parse_command,
)

_ALLOWED = (Write, Wait, Control, SdoWrite)

# Sequences shipped with the package (``run trot`` finds ``sequences/trot.yaml``).
PACKAGED = Path(__file__).resolve().parent / "sequences"


@dataclass(frozen=True)
class Step:
    number: int  # 1-based, as the operator counts
    text: str  # the step as a console line
    command: Command


@dataclass(frozen=True)
class Sequence:
    path: str
    description: str
    steps: tuple[Step, ...]

    @property
    def duration_s(self) -> float:
        return sum(s.command.seconds for s in self.steps if isinstance(s.command, Wait))


def find_sequence(name: str | Path) -> Path:
    """A sequence file by path, or by the name of a packaged sequence (``trot``)."""
    p = Path(name)
    if p.exists() or p.suffix or "/" in str(name):
        return p
    packaged = PACKAGED / f"{name}.yaml"
    return packaged if packaged.exists() else p


def load_sequence(path: str | Path, ctx: ConsoleContext) -> Sequence:
    """Read and check a sequence file. Raises :class:`CommandError` naming the file and step."""
    from ether_ros.errors import ConfigError

    p = find_sequence(path)
    try:
        # The bounded loader of the configuration (a regular file, no alias bombs, no NUL).
        data, _lines = load_yaml(p, "sequence file")
    except ConfigError as exc:
        raise CommandError(str(exc)) from None
    return parse_sequence(data, str(p), ctx)


def parse_sequence(data: Any, name: str, ctx: ConsoleContext) -> Sequence:
    if not isinstance(data, dict) or not isinstance(data.get("steps"), list):
        raise CommandError(f"{name}: a sequence is a mapping with a list 'steps'")
    unknown = set(data) - {"description", "steps"}
    if unknown:
        raise CommandError(f"{name}: unknown key(s) {', '.join(sorted(map(str, unknown)))}")
    steps: list[Step] = []
    for number, raw in enumerate(data["steps"], start=1):
        try:
            line = step_to_line(raw)
            command = parse_command(line, ctx)
        except CommandError as exc:
            raise CommandError(f"{name}: step {number}: {exc}") from None
        if command is None:
            continue
        if not isinstance(command, _ALLOWED):
            raise CommandError(
                f"{name}: step {number}: '{line}' is not allowed in a sequence "
                "(only set, wait, sdo write, start, stop, restart, panic, clear)"
            )
        if isinstance(command, Write):
            ctx = ctx.after(command)
        elif isinstance(command, Control) and command.command == "clear_panic":
            # A clear resets every output to its safe value (the image starts zeroed; the
            # console does not know the configured safe values, so the later steps are
            # checked against zeros, as on a fresh bus).
            ctx = ctx.cleared()
        steps.append(Step(number, line, command))
    if not steps:
        raise CommandError(f"{name}: the sequence has no steps")
    return Sequence(name, str(data.get("description", "")), tuple(steps))


def step_to_line(raw: Any) -> str:
    """One YAML step -> the console line it stands for."""
    if isinstance(raw, str):
        return raw
    if isinstance(raw, dict) and len(raw) == 1:
        ((key, value),) = raw.items()
        key = str(key)
        if key == "wait":
            return f"wait {_scalar(value, 'wait')}"
        if key == "set":
            if not isinstance(value, dict) or set(value) - {"target", "values"}:
                raise CommandError("'set' takes {target: SLAVE|all, values: {VAR: VALUE, ...}}")
            target = value.get("target")
            values = value.get("values")
            if target is None or not isinstance(values, dict) or not values:
                raise CommandError("'set' needs a target and at least one value")
            assignments = " ".join(f"{_word(k)}={_scalar(v, str(k))}" for k, v in values.items())
            return f"set {_word(target)} {assignments}"
        if value is None:
            return key
    raise CommandError(f"a step is a console line or a one-key mapping, not {raw!r}")


def _scalar(value: Any, what: str) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int | float | str):
        return _word(value)
    raise CommandError(f"{what}: {value!r} is not a single value")


def _word(value: Any) -> str:
    text = str(value)
    if not text or any(c.isspace() for c in text):
        raise CommandError(f"'{text}' is not a single word")
    return text
