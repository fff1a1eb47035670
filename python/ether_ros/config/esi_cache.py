"""The on-disk cache of parsed ESI files: a command's second start on the same files skips the
parse (seconds for a vendor's big files, tens of milliseconds from the cache).

An entry is keyed by the file's path (as given and resolved), the SHA-256 of its bytes and the
parser's version (a hash of the parser's own source), so an edited file or a changed parser
never meets a stale entry.
A parse also depends on the files it looked up beside the ESI (the ``<DictionaryFile>``s, and
whether they exist): each lookup is stored with the entry and done again on a hit; any
difference (a file added, removed or changed) is a miss.

Entries are pickles, so the cache is only used in a directory that this user owns and nobody
else can write (as ssh treats its keys); anything else disables it with one warning. Writes go
to a temporary file renamed into place, so concurrent commands never read half an entry; an
entry that does not load is parsed again and rewritten.

``ETHER_ROS_CACHE_DIR`` moves the cache (default ``$XDG_CACHE_HOME/ether_ros``, else
``~/.cache/ether_ros``); ``ETHER_ROS_ESI_CACHE=0`` turns it off.
"""

from __future__ import annotations

import contextlib
import functools
import hashlib
import logging
import os
import pickle
import stat
import tempfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

log = logging.getLogger(__name__)

CACHE_DIR_ENV = "ETHER_ROS_CACHE_DIR"
CACHE_SWITCH_ENV = "ETHER_ROS_ESI_CACHE"
# The modules whose source decides what a parse gives: a change to any is a new parser version.
_PARSER_SOURCES = ("esi.py", "types.py", "esi_cache.py")
# Entries beyond this many are removed, oldest first, when a new one is written.
MAX_ENTRIES = 512


@dataclass(frozen=True)
class Lookup:
    """A file the parse looked for beside the ESI: the folder and the name as the ESI wrote
    it, the path it resolved to (None: none allowed), and the SHA-256 of that file (None: it
    was not there)."""

    folder: str
    name: str
    resolved: str | None
    digest: str | None


def file_digest(path: Path) -> str | None:
    """SHA-256 of a regular file's bytes; None when there is no such file."""
    try:
        with open(path, "rb") as f:
            if not stat.S_ISREG(os.fstat(f.fileno()).st_mode):
                return None
            return hashlib.file_digest(f, "sha256").hexdigest()
    except OSError:
        return None


@functools.cache
def parser_version() -> str:
    here = Path(__file__).resolve().parent
    h = hashlib.sha256()
    for name in _PARSER_SOURCES:
        h.update(name.encode() + b"\0" + (here / name).read_bytes())
    return h.hexdigest()[:16]


@functools.cache
def _warn_once(message: str) -> None:
    log.warning("%s", message)


def cache_dir() -> Path | None:
    """The directory of ESI entries, made if needed; None when the cache is off or the
    directory is not safe to load pickles from."""
    if os.environ.get(CACHE_SWITCH_ENV, "1").strip() in ("0", "off", "no", "false"):
        return None
    base = os.environ.get(CACHE_DIR_ENV)
    if base:
        root = Path(base)
    else:
        xdg = os.environ.get("XDG_CACHE_HOME")
        root = (Path(xdg) if xdg else Path.home() / ".cache") / "ether_ros"
    folder = root / "esi"
    try:
        folder.mkdir(mode=0o700, parents=True, exist_ok=True)
        st = folder.stat()
    except OSError as exc:  # no home, a read-only one: parsing as before is all it costs
        log.debug("ESI cache off: cannot use %s: %s", folder, exc.strerror)
        return None
    if st.st_uid != os.geteuid() or st.st_mode & (stat.S_IWGRP | stat.S_IWOTH):
        _warn_once(
            f"ESI cache off: {folder} must belong to this user and be writable by nobody "
            f"else (owner uid {st.st_uid}, mode {stat.filemode(st.st_mode)})"
        )
        return None
    return folder


def _entry_path(folder: Path, key: str, digest: str) -> Path:
    name = hashlib.sha256(f"{parser_version()}\0{key}\0{digest}".encode()).hexdigest()[:32]
    return folder / f"{name}.pickle"


def load(key: str, digest: str, still_true: Callable[[Lookup], bool]) -> Any | None:
    """The cached parse of the file ``key`` names (its path as given and resolved), whose
    bytes hash to ``digest``, or None. ``still_true`` does a stored lookup again and says
    whether it finds the same file."""
    folder = cache_dir()
    if folder is None:
        return None
    entry = _entry_path(folder, key, digest)
    try:
        with open(entry, "rb") as f:
            st = os.fstat(f.fileno())
            if st.st_uid != os.geteuid() or st.st_mode & (stat.S_IWGRP | stat.S_IWOTH):
                return None
            stored = pickle.load(f)
    except FileNotFoundError:
        return None
    except Exception as exc:  # a torn or foreign entry: parse again, overwrite it
        log.debug("ESI cache entry %s not read (%s): parsing again", entry, exc)
        return None
    if not (
        isinstance(stored, dict)
        and stored.get("parser") == parser_version()
        and stored.get("key") == key
        and stored.get("digest") == digest
    ):
        return None
    lookups = stored.get("lookups", ())
    if not all(isinstance(x, Lookup) and still_true(x) for x in lookups):
        return None
    with contextlib.suppress(OSError):
        os.utime(entry)  # recently used: kept when old entries are trimmed
    return stored.get("esi")


def store(key: str, digest: str, esi: Any, lookups: list[Lookup]) -> None:
    """Writes the entry (atomically); a cache that cannot be written is silently skipped."""
    folder = cache_dir()
    if folder is None:
        return
    entry = _entry_path(folder, key, digest)
    data = {
        "parser": parser_version(),
        "key": key,
        "digest": digest,
        "lookups": tuple(lookups),
        "esi": esi,
    }
    try:
        fd, tmp = tempfile.mkstemp(dir=folder, prefix=".entry-", suffix=".tmp")
        try:
            with os.fdopen(fd, "wb") as f:
                pickle.dump(data, f, protocol=pickle.HIGHEST_PROTOCOL)
            os.replace(tmp, entry)
        finally:
            if os.path.exists(tmp):
                os.unlink(tmp)
        _trim(folder)
    except OSError as exc:
        log.debug("ESI cache entry %s not written: %s", entry, exc)


def _trim(folder: Path) -> None:
    entries = list(folder.glob("*.pickle"))
    if len(entries) <= MAX_ENTRIES:
        return
    entries.sort(key=lambda p: p.stat().st_mtime if p.exists() else 0.0)
    for old in entries[: len(entries) - MAX_ENTRIES]:
        with contextlib.suppress(OSError):
            old.unlink()
