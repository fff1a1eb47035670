"""The disk cache of parsed ESI files (config/esi_cache.py): a second process reads the parse
from disk; an edited ESI, a dictionary file added, changed or removed beside it, a changed
parser and a corrupt entry are all parsed again; an unsafe cache directory is not used.

"A second process" is played by clearing the in-process cache (``esi._cache``), and a parse
from disk is told apart from a fresh one by making the parser raise: the one layer faked here.
"""

from __future__ import annotations

import logging
import os
import shutil
import threading
from collections.abc import Iterator
from pathlib import Path

import pytest

from ether_ros.config import esi, esi_cache

DATA = Path(__file__).resolve().parents[1] / "data" / "esi"


@pytest.fixture
def cache(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[Path]:
    folder = tmp_path / "cache"
    monkeypatch.setenv(esi_cache.CACHE_DIR_ENV, str(folder))
    monkeypatch.delenv(esi_cache.CACHE_SWITCH_ENV, raising=False)
    esi._cache.clear()
    yield folder / "esi"
    esi._cache.clear()


def _copy(tmp_path: Path, *names: str) -> Path:
    folder = tmp_path / "esi"
    folder.mkdir(exist_ok=True)
    for name in names:
        shutil.copy(DATA / name, folder / name)
    return folder / names[0]


def _new_process() -> None:
    esi._cache.clear()


def _parser_must_not_run(monkeypatch: pytest.MonkeyPatch) -> None:
    def refuse(p: Path) -> esi.EsiFile:
        raise AssertionError(f"parsed {p} again: the disk cache was not used")

    monkeypatch.setattr(esi, "_parse_file", refuse)


def test_a_second_process_reads_the_parse_from_disk(
    cache: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    path = _copy(tmp_path, "dictfile_counter.xml", "dictfile_counter_dictionary.xml")
    first = esi.load_esi_file(path)
    assert len(list(cache.glob("*.pickle"))) == 1
    _new_process()
    _parser_must_not_run(monkeypatch)
    again = esi.load_esi_file(path)
    assert again == first
    assert again.devices[0].objects  # the dictionary from the separate file came along


def test_an_edited_file_is_parsed_again(
    cache: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    path = _copy(tmp_path, "dictfile_counter.xml", "dictfile_counter_dictionary.xml")
    esi.load_esi_file(path)
    path.write_text(path.read_text().replace("<!--", "<!-- edited", 1))
    _new_process()
    _parser_must_not_run(monkeypatch)
    with pytest.raises(AssertionError, match=r"parsed .* again"):
        esi.load_esi_file(path)


def _count_parses(monkeypatch: pytest.MonkeyPatch) -> list[Path]:
    parses: list[Path] = []
    parse = esi._parse_file

    def counted(p: Path) -> esi.EsiFile:
        parses.append(p)
        return parse(p)

    monkeypatch.setattr(esi, "_parse_file", counted)
    return parses


@pytest.mark.parametrize("change", ["removed", "changed"])
def test_a_dictionary_file_changed_beside_the_esi_is_a_miss(
    cache: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, change: str
) -> None:
    path = _copy(tmp_path, "dictfile_counter.xml", "dictfile_counter_dictionary.xml")
    parses = _count_parses(monkeypatch)
    with_dictionary = esi.load_esi_file(path)
    dictionary = path.parent / "dictfile_counter_dictionary.xml"
    if change == "removed":
        dictionary.unlink()
    else:
        dictionary.write_text(dictionary.read_text().replace("<!--", "<!-- changed", 1) + " ")
    _new_process()
    again = esi.load_esi_file(path)
    if change == "removed":
        assert not again.devices[0].objects
        assert any("DictionaryFile not found" in str(w) for w in again.warnings)
    else:
        assert again == with_dictionary  # same content parsed again: the same result
    assert len(parses) == 2  # the lookup stored with the entry no longer held


def test_a_dictionary_file_added_later_is_read(cache: Path, tmp_path: Path) -> None:
    path = _copy(tmp_path, "dictfile_counter.xml")
    without = esi.load_esi_file(path)
    assert not without.devices[0].objects
    shutil.copy(DATA / "dictfile_counter_dictionary.xml", path.parent)
    _new_process()
    assert esi.load_esi_file(path).devices[0].objects


def test_another_parser_version_does_not_meet_the_old_entries(
    cache: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    path = _copy(tmp_path, "dictfile_counter.xml", "dictfile_counter_dictionary.xml")
    esi.load_esi_file(path)
    _new_process()
    monkeypatch.setattr(esi_cache, "parser_version", lambda: "another-parser")
    _parser_must_not_run(monkeypatch)
    with pytest.raises(AssertionError, match=r"parsed .* again"):
        esi.load_esi_file(path)


@pytest.mark.parametrize("damage", [b"", b"not a pickle", b"\x80\x05garbage"])
def test_a_corrupt_entry_is_parsed_again_and_rewritten(
    cache: Path, tmp_path: Path, damage: bytes
) -> None:
    path = _copy(tmp_path, "dictfile_counter.xml", "dictfile_counter_dictionary.xml")
    first = esi.load_esi_file(path)
    (entry,) = cache.glob("*.pickle")
    entry.write_bytes(damage)
    _new_process()
    assert esi.load_esi_file(path) == first
    assert entry.stat().st_size > 100  # rewritten whole


def test_a_directory_others_can_write_is_not_used(
    cache: Path, tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    cache.mkdir(parents=True)
    cache.chmod(0o777)
    esi_cache._warn_once.cache_clear()
    path = _copy(tmp_path, "dictfile_counter.xml", "dictfile_counter_dictionary.xml")
    with caplog.at_level(logging.WARNING):
        esi.load_esi_file(path)
    assert not list(cache.glob("*.pickle"))
    assert any("writable by nobody else" in r.getMessage() for r in caplog.records)


def test_the_switch_turns_it_off(
    cache: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv(esi_cache.CACHE_SWITCH_ENV, "0")
    esi.load_esi_file(_copy(tmp_path, "dictfile_counter.xml"))
    assert not cache.exists() or not list(cache.glob("*.pickle"))


def test_concurrent_writers_and_readers_never_see_half_an_entry(
    cache: Path, tmp_path: Path
) -> None:
    path = _copy(tmp_path, "dictfile_counter.xml", "dictfile_counter_dictionary.xml")
    parsed = esi.load_esi_file(path)
    key, digest = f"{path}\0{path.resolve()}", esi_cache.file_digest(path)
    assert digest is not None
    seen: list[object] = []

    def write() -> None:
        for _ in range(20):
            esi_cache.store(key, digest, parsed, [])

    def read() -> None:
        for _ in range(100):
            seen.append(esi_cache.load(key, digest, lambda _lookup: True))

    threads = [threading.Thread(target=write) for _ in range(2)]
    threads += [threading.Thread(target=read) for _ in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert seen and all(s == parsed for s in seen)
    assert not [p for p in os.listdir(cache) if p.endswith(".tmp")]
