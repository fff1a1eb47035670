"""YAML loading that remembers where every value came from, so errors can name the line.

PyYAML's safe loader (YAML 1.1) is used: ``0x0A12`` is an int, ``yes``/``no`` are bools.
Duplicate keys, which PyYAML would silently accept, are errors here.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml

from ether_ros.errors import ConfigError

KeyPath = tuple[str | int, ...]


def format_path(path: KeyPath) -> str:
    """``("slaves", 2, "safe_outputs", "X")`` → ``slaves[2].safe_outputs.X``."""
    out = ""
    for part in path:
        if isinstance(part, int):
            out += f"[{part}]"
        else:
            out += f".{part}" if out else str(part)
    return out or "(top level)"


class SourceMap:
    """Line numbers (1-based) of the values (and keys) of a loaded YAML document."""

    def __init__(self, file: Path) -> None:
        self.file = file
        self.lines: dict[KeyPath, int] = {}

    def line(self, path: KeyPath) -> int | None:
        """Line of ``path`` or of its nearest ancestor that has one."""
        p = tuple(path)
        while True:
            if p in self.lines:
                return self.lines[p]
            if not p:
                return None
            p = p[:-1]

    def error(
        self, path: KeyPath, msg: str, value: Any = None, *, show_value: bool = True
    ) -> ConfigError:
        line = self.line(path)
        where = f"{self.file}:{line}" if line else str(self.file)
        tail = f" (got {value!r})" if show_value else ""
        return ConfigError(
            f"{where}: {format_path(path)}: {msg}{tail}",
            file=str(self.file),
            line=line or None,
            field=format_path(path),
            value=value,
        )


def load_yaml(path: Path) -> tuple[Any, SourceMap]:
    """Parse ``path``; return plain Python data and the source map of its values."""
    smap = SourceMap(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ConfigError(f"{path}: bus configuration file not found") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{path}: cannot read: {exc}") from None
    loader = yaml.SafeLoader(text)
    try:
        node = loader.get_single_node()
        if node is None:
            return None, smap
        return _build(loader, node, (), smap), smap
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        number = mark.line + 1 if mark is not None else None
        line = f":{number}" if number is not None else ""
        raise ConfigError(
            f"{path}{line}: invalid YAML: {exc.problem or exc.context}",
            file=str(path),
            line=number,
            field="",
        ) from None
    except yaml.YAMLError as exc:
        raise ConfigError(f"{path}: invalid YAML: {exc}") from None
    finally:
        loader.dispose()


def _build(loader: yaml.SafeLoader, node: yaml.Node, path: KeyPath, smap: SourceMap) -> Any:
    smap.lines.setdefault(path, node.start_mark.line + 1)
    if isinstance(node, yaml.MappingNode):
        loader.flatten_mapping(node)  # resolve merge keys (<<)
        out: dict[Any, Any] = {}
        for key_node, value_node in node.value:
            key = loader.construct_object(key_node, deep=True)
            if not isinstance(key, str | int | float | bool):
                raise smap.error(path, "mapping keys must be plain values", key)
            if key in out:
                line = key_node.start_mark.line + 1
                field = format_path((*path, str(key)))
                raise ConfigError(
                    f"{smap.file}:{line}: {field}: duplicate key",
                    file=str(smap.file),
                    line=line,
                    field=field,
                    value=key,
                )
            sub = (*path, key if isinstance(key, str) else str(key))
            smap.lines[sub] = value_node.start_mark.line + 1
            out[key] = _build(loader, value_node, sub, smap)
        return out
    if isinstance(node, yaml.SequenceNode):
        return [_build(loader, item, (*path, i), smap) for i, item in enumerate(node.value)]
    return loader.construct_object(node, deep=True)
