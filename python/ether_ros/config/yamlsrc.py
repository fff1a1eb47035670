"""YAML loading that remembers where every value came from, so errors can name the line, and
that a hostile or broken file cannot make hang, grow without bound or crash.

PyYAML's safe loader (YAML 1.1) is used: ``0x0A12`` is an int, ``yes``/``no`` are bools.
Duplicate keys, which PyYAML would silently accept, are errors here.

Bounds (each refused with a :class:`ConfigError` naming file and line, never a traceback):

- the file: a regular file of at most :data:`MAX_YAML_BYTES` (a FIFO or ``/dev/urandom`` is
  refused before anything is read), UTF-8;
- nesting: at most :data:`MAX_DEPTH` levels (PyYAML composes recursively);
- aliases: at most :data:`MAX_ALIASES` uses, adding at most :data:`MAX_ALIAS_VALUES` values
  (an alias bomb — nine anchors each listing the previous nine times — expands to 10⁹ values
  from a few hundred bytes), and the whole document at most :data:`MAX_VALUES` values; an
  alias inside its own anchor (a recursive document) is too deep;
- scalars: at most :data:`MAX_SCALAR_CHARS` characters, integers of at most 64 bits, only plain
  values (no ``!!binary``, ``!!timestamp``, ``!!set``), strings without NUL or control
  characters other than tab and newline, and without lone surrogates (``"\\ud800"``).
"""

from __future__ import annotations

import unicodedata
from pathlib import Path
from typing import Any

import yaml

from ether_ros.config.files import read_text
from ether_ros.errors import ConfigError

KeyPath = tuple[str | int, ...]

#: Largest YAML file read (a 1024-slave bus configuration is about 100 kB).
MAX_YAML_BYTES = 4 * 1024 * 1024
#: Deepest nesting of mappings and sequences (a bus configuration needs 6).
MAX_DEPTH = 32
#: Most alias uses (``*name``) in one document.
MAX_ALIASES = 256
#: Most values (scalars, mappings and sequences, aliases expanded) in one document.
MAX_VALUES = 250_000
#: Most values that aliases may add (a merge key ``<<: *defaults`` used by every slave of a
#: 128-slave bus adds about 1300).
MAX_ALIAS_VALUES = 10_000
#: Longest scalar, in characters.
MAX_SCALAR_CHARS = 4096
#: Widest integer, in bits (plus the sign): every integer the configuration takes fits.
MAX_INT_BITS = 64
#: How much of an offending value an error message shows.
SHOWN_CHARS = 80


def format_path(path: KeyPath) -> str:
    """``("slaves", 2, "safe_outputs", "X")`` → ``slaves[2].safe_outputs.X``."""
    out = ""
    for part in path:
        if isinstance(part, int):
            out += f"[{part}]"
        else:
            out += f".{part}" if out else str(part)
    return out or "(top level)"


def shown(value: Any) -> str:
    """``repr(value)``, cut to :data:`SHOWN_CHARS` characters (a 4000-digit number or a long
    string is named, not echoed)."""
    text = repr(value)
    if len(text) > SHOWN_CHARS:
        return f"{text[: SHOWN_CHARS - 20]}... ({len(text)} characters)"
    return text


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
        field = format_path(path)
        tail = f" (got {shown(value)})" if show_value else ""
        return ConfigError(
            f"{where}: {field}: {msg}{tail}",
            file=self.file,
            line=line or None,
            field=field,
            value=value,
        )


def text_problem(text: str) -> str | None:
    """Why ``text`` may not appear in a YAML value or key: a NUL or other control character
    (tab and newline excepted), or a lone surrogate that no file encoding can hold."""
    for i, ch in enumerate(text):
        if ch in "\t\n":
            continue
        category = unicodedata.category(ch)
        if category == "Cc":
            return f"control character {ch!r} at character {i}"
        if category == "Cs":
            return f"lone surrogate {ch!r} at character {i}"
    return None


class _Refused(Exception):
    """A bound crossed while composing, at ``path`` (line ``line``)."""

    def __init__(self, path: KeyPath, line: int, message: str) -> None:
        super().__init__(message)
        self.path = path
        self.line = line


class _BoundedLoader(yaml.SafeLoader):
    """The safe loader with nesting, aliases and scalar size bounded while composing; it keeps
    the key path of the node being composed, so a refusal names the field."""

    def __init__(self, stream: str) -> None:
        super().__init__(stream)
        self._path: list[str | int] = []
        self._aliases = 0

    def compose_node(self, parent: yaml.Node | None, index: Any) -> yaml.Node:
        event = self.peek_event()
        line = event.start_mark.line + 1
        # PyYAML passes a mapping value's key node as ``index``, a sequence item's position.
        if isinstance(parent, yaml.SequenceNode) and isinstance(index, int):
            part: str | int | None = index
        elif isinstance(parent, yaml.MappingNode) and isinstance(index, yaml.ScalarNode):
            part = str(index.value)[:SHOWN_CHARS]
        else:
            part = None  # the document, or a mapping key
        path = (*self._path, part) if part is not None else tuple(self._path)
        if isinstance(event, yaml.AliasEvent):
            self._aliases += 1
            if self._aliases > MAX_ALIASES:
                raise _Refused(path, line, f"more than {MAX_ALIASES} aliases in one document")
        elif isinstance(event, yaml.ScalarEvent) and len(event.value) > MAX_SCALAR_CHARS:
            raise _Refused(
                path, line, f"a value of {len(event.value)} characters (at most {MAX_SCALAR_CHARS})"
            )
        if len(path) > MAX_DEPTH:
            raise _Refused(path[:MAX_DEPTH], line, f"nested deeper than {MAX_DEPTH} levels")
        if part is not None:
            self._path.append(part)
        try:
            node: yaml.Node | None = super().compose_node(parent, index)
            assert node is not None  # a node follows every event compose_node is called for
            return node
        finally:
            if part is not None:
                self._path.pop()


def load_yaml(path: Path, what: str = "bus configuration file") -> tuple[Any, SourceMap]:
    """Parse ``path``; return plain Python data and the source map of its values. ``what``
    names the kind of file in errors."""
    smap = SourceMap(path)
    text = read_text(path, MAX_YAML_BYTES, what)
    loader: _BoundedLoader | None = None
    try:
        loader = _BoundedLoader(text)  # checks every character of the text first
        node = loader.get_single_node()
        if node is None:
            return None, smap
        return _Builder(loader, smap).build(node, ()), smap
    except _Refused as exc:
        raise ConfigError(
            f"{path}:{exc.line}: {format_path(exc.path)}: {exc}",
            file=path,
            line=exc.line,
            field=format_path(exc.path),
        ) from None
    except yaml.reader.ReaderError as exc:
        line = text.count("\n", 0, max(exc.position, 0)) + 1
        ch = chr(exc.character) if isinstance(exc.character, int) else exc.character
        raise ConfigError(
            f"{path}:{line}: invalid YAML: character {ch!r} is not allowed in YAML"
            " (NUL and other control characters)",
            file=path,
            line=line,
        ) from None
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        at = mark.line + 1 if mark is not None else None
        where = f"{path}:{at}" if at is not None else str(path)
        raise ConfigError(
            f"{where}: invalid YAML: {exc.problem or exc.context}", file=path, line=at, field=""
        ) from None
    except yaml.YAMLError as exc:
        raise ConfigError(f"{path}: invalid YAML: {exc}", file=path) from None
    finally:
        if loader is not None:
            loader.dispose()


class _Builder:
    """Plain data from the composed node graph, with every value's line, every alias expanded
    within :data:`MAX_VALUES` and every scalar checked."""

    def __init__(self, loader: yaml.SafeLoader, smap: SourceMap) -> None:
        self.loader = loader
        self.smap = smap
        self.values = 0
        self.alias_values = 0
        # Nodes built once: building one again is an alias expanding.
        self.built: set[int] = set()
        self.in_alias = 0

    def build(self, node: yaml.Node, path: KeyPath) -> Any:
        line = node.start_mark.line + 1
        self.values += 1
        if self.values > MAX_VALUES:
            raise self.smap.error(
                path, f"the document expands to more than {MAX_VALUES} values", show_value=False
            )
        again = id(node) in self.built
        self.built.add(id(node))
        self.in_alias += again
        try:
            if self.in_alias:
                self.alias_values += 1
                if self.alias_values > MAX_ALIAS_VALUES:
                    raise ConfigError(
                        f"{self.smap.file}:{line}: {format_path(path)}: aliases expand to more"
                        f" than {MAX_ALIAS_VALUES} values (an alias bomb?)",
                        file=self.smap.file,
                        line=line,
                        field=format_path(path),
                    )
            self.smap.lines.setdefault(path, line)
            return self._build(node, path)
        finally:
            self.in_alias -= again

    def _build(self, node: yaml.Node, path: KeyPath) -> Any:
        if len(path) > MAX_DEPTH:
            raise self.smap.error(
                path, f"nested deeper than {MAX_DEPTH} levels (an alias inside itself?)",
                show_value=False,
            )  # fmt: skip
        if isinstance(node, yaml.MappingNode):
            return self._mapping(node, path)
        if isinstance(node, yaml.SequenceNode):
            return [self.build(item, (*path, i)) for i, item in enumerate(node.value)]
        return self._scalar(node, path)

    def _mapping(self, node: yaml.MappingNode, path: KeyPath) -> dict[Any, Any]:
        self.loader.flatten_mapping(node)  # resolve merge keys (<<)
        out: dict[Any, Any] = {}
        for key_node, value_node in node.value:
            if not isinstance(key_node, yaml.ScalarNode):
                raise self.smap.error(path, "mapping keys must be plain values", show_value=False)
            key = self._scalar(key_node, path)
            if key is None:
                raise self.smap.error(path, "a mapping key is empty (null)", show_value=False)
            if key in out:
                line = key_node.start_mark.line + 1
                field = format_path((*path, str(key)))
                raise ConfigError(
                    f"{self.smap.file}:{line}: {field}: duplicate key",
                    file=self.smap.file,
                    line=line,
                    field=field,
                    value=key,
                )
            sub = (*path, key if isinstance(key, str) else str(key))
            self.smap.lines[sub] = value_node.start_mark.line + 1
            out[key] = self.build(value_node, sub)
        return out

    def _scalar(self, node: yaml.Node, path: KeyPath) -> Any:
        try:
            value = self.loader.construct_object(node, deep=True)
        except ValueError as exc:  # e.g. a date that does not exist (!!timestamp)
            raise self.smap.error(path, f"not a usable value: {exc}", node.value) from None
        if value is None or isinstance(value, bool | float):
            return value
        if isinstance(value, int):
            if value.bit_length() > MAX_INT_BITS:
                raise self.smap.error(
                    path, f"integer wider than {MAX_INT_BITS} bits", show_value=False
                )
            return value
        if isinstance(value, str):
            problem = text_problem(value)
            if problem is not None:
                raise self.smap.error(path, f"text holds a {problem}", value)
            return value
        tag = node.tag.rsplit(":", 1)[-1]
        raise self.smap.error(
            path, f"values of type !!{tag} are not used here (plain values only)", node.value
        )
