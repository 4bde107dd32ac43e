"""Stale temporary files of atomic writes: removed only when no live writer holds them."""

from __future__ import annotations

import os
from pathlib import Path

from ravenmem.fsio import atomic_open, is_temp_file, remove_stale_temp_files


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
