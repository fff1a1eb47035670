"""The shell and Python examples of README.md and docs/*.md, as a test runs them.

A fenced block whose language is ``sh``/``bash``/``shell`` or ``python`` is an example. The
HTML comments on the lines right before it say how the docs test treats it:

- ``<!-- not-run: REASON -->``: it cannot run here (a real NIC, a real robot, the whole build);
  the test lists it with the reason.
- ``<!-- docs-test: sim=PATH -->``: the simulated bus it needs (a bus configuration, or an ESI
  file with ``esi=PATH device=TYPE count=N``); default ``config/laelaps.yaml``.
- ``<!-- docs-test: continues -->``: a Python block that goes on from the file's previous
  Python block (that one runs first, in the same interpreter).
- ``<!-- docs-expect: REGEX -->``: what the example must print for its claim to hold (a
  result code, a state): the test fails unless its standard output matches ``REGEX``
  (``re.search``, multi-line). An example that exits non-zero or prints a traceback fails
  anyway; this is for an example whose success shows in what it prints.

Interface names are substituted: the master's side of the docs (``veth0``, ``ecat0``, ``eth1``,
``enp5s0``) becomes the test's master end of a veth pair, the simulator's side (``veth1``,
``ecat0s``) its end in the simulator's network namespace; the docs' RT CPU (``--cpu 3``) the
host's last CPU.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path

SHELL_LANGUAGES = {"sh", "bash", "shell"}
PYTHON_LANGUAGES = {"python", "py"}
MASTER_NAMES = ("veth0", "ecat0", "eth1", "enp5s0")
SIM_NAMES = ("veth1", "ecat0s")
DEFAULT_SIM = "config/laelaps.yaml"
DOC_CPU = 3

_FENCE = re.compile(r"^(`{3,})\s*([\w+-]*)")
_NOT_RUN = re.compile(r"<!--\s*not-run:\s*(.+?)\s*-->")
_DIRECTIVE = re.compile(r"<!--\s*docs-test:\s*(.+?)\s*-->")
_EXPECT = re.compile(r"<!--\s*docs-expect:\s*(.+?)\s*-->")


@dataclass
class Block:
    """One example: where it is, its language (``sh`` or ``python``) and text."""

    path: Path
    line: int  # of the opening fence, 1-based
    lang: str
    text: str
    not_run: str | None = None
    options: dict[str, str] = field(default_factory=dict)
    expect: str | None = None  # a regex its standard output must match

    @property
    def where(self) -> str:
        first = self.text.strip().splitlines()[0] if self.text.strip() else ""
        return f"{self.path.name}:{self.line} ({self.lang}: {first[:60]})"


def blocks(path: Path) -> list[Block]:
    """The shell and Python examples of one markdown file, with their directives."""
    lines = path.read_text().splitlines()
    found: list[Block] = []
    i = 0
    while i < len(lines):
        fence = _FENCE.match(lines[i])
        if not fence:
            i += 1
            continue
        ticks, lang = fence.group(1), fence.group(2).lower()
        start = i
        i += 1
        body: list[str] = []
        while i < len(lines) and not lines[i].startswith(ticks):
            body.append(lines[i])
            i += 1
        i += 1
        kind = "sh" if lang in SHELL_LANGUAGES else "python" if lang in PYTHON_LANGUAGES else None
        if kind is None:
            continue
        block = Block(path, start + 1, kind, "\n".join(body) + "\n")
        j = start - 1
        while j >= 0 and (not lines[j].strip() or lines[j].lstrip().startswith("<!--")):
            text = lines[j]
            if (m := _NOT_RUN.search(text)) is not None:
                block.not_run = m.group(1)
            if (m := _EXPECT.search(text)) is not None:
                re.compile(m.group(1))  # a bad regex fails at collection, naming the block
                block.expect = m.group(1)
            elif (m := _DIRECTIVE.search(text)) is not None:
                for word in m.group(1).split():
                    key, _, value = word.partition("=")
                    block.options[key] = value
            j -= 1
        found.append(block)
    return found


def substitute(text: str, master: str, sim: str, cpu: int | None = None) -> str:
    """The example with the docs' interface names replaced by the test's, and the docs' RT
    CPU (``--cpu 3``, a 4-CPU machine) by ``cpu`` when given."""
    if cpu is not None:
        text = re.sub(rf"--cpu {DOC_CPU}\b", f"--cpu {cpu}", text)
    for name in SIM_NAMES:
        text = re.sub(rf"\b{name}\b", sim, text)
    for name in MASTER_NAMES:
        text = re.sub(rf"\b{name}\b", master, text)
    return text


def doc_files(repo: Path) -> list[Path]:
    return [repo / "README.md", *sorted((repo / "docs").glob("*.md"))]
