"""The writer lock (ravenmem.memory.lock) and how Memory takes it."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

import ravenmem
from ravenmem.errors import MemoryBusyError
from ravenmem.memory.folder import LOCK
from ravenmem.memory.lock import WriterLock
from ravenmem.types import Pose
from tests.conftest import solid

REPO = Path(__file__).resolve().parents[2]


def test_one_holder_per_folder_even_within_a_process(tmp_path: Path) -> None:
    a, b = WriterLock(tmp_path), WriterLock(tmp_path)
    a.acquire()
    assert a.held and json.loads((tmp_path / LOCK).read_text())["pid"] == os.getpid()
    with pytest.raises(MemoryBusyError, match="another Memory object in this process"):
        b.acquire()
    t0 = time.monotonic()
    with pytest.raises(MemoryBusyError, match=r"after waiting 0\.3 s"):
        b.acquire(wait=0.3)
    assert 0.25 <= time.monotonic() - t0 < 5
    a.release()
    b.acquire(wait=False)
    assert b.held and not a.held
    b.release()
    assert (tmp_path / LOCK).read_text() == ""  # nobody to name any more
    with pytest.raises(ValueError):
        a.acquire(wait=-1)


def _hold(python: str, folder: Path) -> subprocess.Popen[str]:
    """A process that takes `folder`'s lock, says 'held', then sleeps (to be killed)."""
    code = (
        "import sys, time; from ravenmem.memory.lock import WriterLock; "
        "lk = WriterLock(sys.argv[1]); lk.acquire(); print('held', flush=True); time.sleep(600)"
    )
    env = dict(os.environ, PYTHONPATH=str(REPO / "src"))
    return subprocess.Popen([python, "-c", code, str(folder)], stdout=subprocess.PIPE, text=True, env=env)


def _named_then_freed(proc: subprocess.Popen[str], folder: Path) -> str:
    """The busy message while `proc` holds the lock; then kill it and take the lock."""
    try:
        assert proc.stdout is not None and proc.stdout.readline().strip() == "held"
        with pytest.raises(MemoryBusyError) as e:
            WriterLock(folder).acquire()
        msg = str(e.value)
        assert f"pid {proc.pid}" in msg and "time.sleep(600)" in msg and "\n" not in msg
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait()
    lock = WriterLock(folder)
    lock.acquire(wait=False)  # the kernel dropped the dead holder's lock: no stale pid to clear
    lock.release()
    return msg


def test_a_killed_holder_frees_the_lock_and_is_named_while_alive(tmp_path: Path) -> None:
    _named_then_freed(_hold(sys.executable, tmp_path), tmp_path)


def test_the_holder_is_named_whatever_the_length_of_the_checkouts_path(tmp_path: Path) -> None:
    """A venv and a memory at long paths (a user's clone can be anywhere): the message still
    names the program, the end of its code and the end of the folder, and stays short."""
    venv = tmp_path.joinpath(*["a-rather-long-folder-name-of-a-users-clone"] * 6, ".venv")
    (venv / "bin").mkdir(parents=True)
    (venv / "pyvenv.cfg").write_text((Path(sys.prefix) / "pyvenv.cfg").read_text())
    (venv / "lib").symlink_to(Path(sys.prefix) / "lib")  # the same packages, at the long path
    (venv / "bin" / "python").symlink_to(Path(sys.executable).resolve())
    folder = tmp_path.joinpath(*["a-memory-folder-deep-inside-the-users-projects"] * 5, "m.mem")
    folder.mkdir(parents=True)
    proc = _hold(str(venv / "bin" / "python"), folder)
    msg = _named_then_freed(proc, folder)
    assert len(str(venv)) > 250 and len(str(folder)) > 200
    command = msg.split(f"pid {proc.pid} (")[1].split(") since ")[0]
    assert command.startswith("python -c ") and str(venv) not in command
    assert command.endswith("m.mem") and len(command) <= 200, command


def test_memory_takes_the_lock_to_write_and_reads_fresh_state(tmp_path: Path, color_embedder: object) -> None:
    path = tmp_path / "m.mem"
    writer = ravenmem.create(path, embedder=color_embedder, ocr=False)  # type: ignore[arg-type]
    assert writer.is_writer
    reader = ravenmem.open(path, embedder=color_embedder)  # type: ignore[arg-type]
    assert not reader.is_writer
    first = writer.add(solid("red"), Pose(0, 0), t=10.0)
    with pytest.raises(MemoryBusyError):
        reader.add(solid("blue"), Pose(1, 0), t=11.0)
    with pytest.raises(MemoryBusyError):
        ravenmem.open(path, writable=True)
    second = writer.add(solid("green"), Pose(2, 0), t=12.0)
    writer.record_ingest({"source": "a", "frames_seen": 2})
    writer.close()
    assert not writer.is_writer

    # the reader opened when the store held one memory; its first write re-reads the store
    third = reader.add(solid("blue"), Pose(1, 0), t=11.0)
    assert reader.is_writer and third > second > first and reader.count() == 3
    reader.record_ingest({"source": "b", "frames_seen": 1})
    assert [r["source"] for r in reader.manifest.ingests] == ["a", "b"]  # the writer's kept
    reader.release_writer()
    again = ravenmem.open(path, writable=True, wait=1.0)
    try:
        assert again.is_writer and again.count() == 3
        with pytest.raises(MemoryBusyError):
            reader.acquire_writer(wait=0.1)
    finally:
        again.close()
        reader.close()
