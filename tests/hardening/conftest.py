"""Fixtures of the hardening tests: the command driver (one interpreter, a process per command
line, see `forkrun.py`) and snapshots of a folder's files (what "changes no file" is checked on)."""

from __future__ import annotations

import hashlib
import os
from collections.abc import Iterator
from pathlib import Path

import pytest

from tests.hardening.runner import Driver


@pytest.fixture(scope="module")
def driver() -> Iterator[Driver]:
    d = Driver()
    yield d
    d.close()


def snapshot(folder: Path) -> dict[str, tuple[int, int, str]]:
    """Every entry below `folder`: path -> (size, mtime in ns, sha1 of the bytes; '' for a folder)."""
    out: dict[str, tuple[int, int, str]] = {}
    for root, dirs, files in os.walk(folder):
        for name in dirs + files:
            p = Path(root) / name
            st = p.lstat()
            digest = hashlib.sha1(p.read_bytes()).hexdigest() if p.is_file() else ""
            out[str(p.relative_to(folder))] = (st.st_size, st.st_mtime_ns, digest)
    return out


def one_line_error(r: dict[str, object]) -> str:
    """The driver's result of a refused command: exit 2 and one `error: ...` line; the line."""
    err = str(r["stderr"]).strip().splitlines()
    assert r["rc"] == 2 and len(err) == 1 and err[0].startswith("error: "), r
    assert "Traceback" not in str(r["stdout"]), r
    return err[0]
