"""What a benchmark module hands back: Markdown for docs/benchmarks.md plus raw numbers.

Every ``bench/bench_*.py`` exposes ``run(report: Report) -> None``; it measures, then describes
what it measured with ``report.text``/``report.table`` and records the numbers with
``report.value`` (kept as JSON next to the Markdown, for comparisons between runs).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any


class BenchSkipped(Exception):
    """A benchmark cannot run here (missing tool, module not built yet); the reason is shown."""


@dataclass
class Report:
    """The output of one benchmark module."""

    name: str
    quick: bool = False
    lines: list[str] = field(default_factory=list)
    values: dict[str, Any] = field(default_factory=dict)

    def text(self, markdown: str) -> None:
        """A paragraph (or any Markdown block)."""
        self.lines.append(markdown.rstrip() + "\n")

    def table(self, headers: list[str], rows: list[list[Any]]) -> None:
        """A Markdown table; cells are formatted with ``str``."""
        out = ["| " + " | ".join(headers) + " |", "|" + "---|" * len(headers)]
        out += ["| " + " | ".join(str(c) for c in row) + " |" for row in rows]
        self.lines.append("\n".join(out) + "\n")

    def value(self, key: str, value: Any) -> None:
        """A raw result, stored in the JSON results under this module's name."""
        self.values[key] = value

    def markdown(self) -> str:
        return "\n".join(self.lines)


def us(ns: float | int) -> str:
    """Nanoseconds as microseconds with one decimal."""
    return f"{ns / 1000:.1f}"
