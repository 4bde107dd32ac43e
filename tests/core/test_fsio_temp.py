"""Stale temporary files of atomic writes: removed only when no live writer holds them."""

from __future__ import annotations

import os
import time
from pathlib import Path

import pytest

from ravenmem.fsio import atomic_open, is_temp_file, publish_dir, remove_stale_temp_files


def test_a_temp_file_being_written_is_never_removed(tmp_path: Path) -> None:
    with atomic_open(tmp_path / "index.faiss") as f:
        f.write(b"half")
        (tmp,) = [p for p in tmp_path.iterdir() if is_temp_file(p)]
        os.utime(tmp, (0, 0))  # old enough, but its writer holds the lock
        assert remove_stale_temp_files(tmp_path, min_age=0) == []
        f.write(b" and the rest")
    assert (tmp_path / "index.faiss").read_bytes() == b"half and the rest"
    assert [p for p in tmp_path.iterdir() if is_temp_file(p)] == []


def test_only_unlocked_old_files_with_ravenmem_names_go(tmp_path: Path) -> None:
    dead = tmp_path / ".memory.json.0123456789ab.tmp"  # a killed writer's (nobody holds it)
    young = tmp_path / ".memory.json.ba9876543210.tmp"  # could be a writer between open and lock
    others = [
        tmp_path / n for n in (".memory.json.tmp", "a.0123456789ab.tmp", ".x.0123456789AB.tmp", "x.json")
    ]
    for p in [dead, young, *others]:
        p.write_bytes(b"x")
    for p in [dead, *others]:
        os.utime(p, (0, 0))
    assert remove_stale_temp_files(tmp_path) == [dead]
    assert young.exists() and all(p.exists() for p in others)
    assert remove_stale_temp_files(tmp_path / "missing") == []
    assert remove_stale_temp_files(tmp_path, min_age=0, target="index.faiss") == []  # another target


def test_a_folder_built_under_a_temporary_name_is_published_whole(tmp_path: Path) -> None:
    tmp, final = tmp_path / ".cache.building-1", tmp_path / "cache"
    tmp.mkdir()
    (tmp / "done.json").write_text("{}")
    publish_dir(tmp, final)
    assert not tmp.exists() and (final / "done.json").read_text() == "{}"
    again = tmp_path / ".cache.building-2"
    again.mkdir()
    with pytest.raises(FileExistsError):
        publish_dir(again, final)
    assert again.is_dir() and (final / "done.json").exists()


def test_renames_happen_only_in_fsio() -> None:
    """Every crash-safe replace goes through `ravenmem.fsio` (no hand-written tmp + rename)."""
    import re

    src = Path(__file__).resolve().parents[2] / "src" / "ravenmem"
    rename = re.compile(r"\bos\.(replace|rename)\(|\.rename\(")
    found = [
        f"{p.relative_to(src)}:{i}"
        for p in sorted(src.rglob("*.py"))
        if p.name != "fsio.py"
        for i, line in enumerate(p.read_text(encoding="utf-8").splitlines(), 1)
        if rename.search(line)
    ]
    assert found == []


def test_waiting_removes_a_leftover_of_an_instant_ago_but_never_a_held_file(tmp_path: Path) -> None:
    """What the next writer does right after a kill -9: the killed writer's temporary file is
    younger than the age guard; waiting it out removes it, a live writer's file stays."""
    dead = tmp_path / ".columns.cache.0123456789ab.tmp"  # killed an instant ago: young, unlocked
    dead.write_bytes(b"x")
    with atomic_open(tmp_path / "index.faiss") as f:  # a live writer's: young and locked
        f.write(b"half")
        assert remove_stale_temp_files(tmp_path, min_age=0.5, wait=True) == [dead]
        f.write(b" and the rest")
    assert (tmp_path / "index.faiss").read_bytes() == b"half and the rest"
    assert [p for p in tmp_path.iterdir() if is_temp_file(p)] == []
    start = time.monotonic()
    assert remove_stale_temp_files(tmp_path, min_age=600, wait=True) == []
    assert time.monotonic() - start < 300  # nothing young: no wait (a wait would be 600 s)
