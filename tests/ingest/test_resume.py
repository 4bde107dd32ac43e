"""Resume, clean-up and the writer lock, as a user meets them: the real command in subprocesses.

* kill -9 at a random moment, then the same `ingest` command: every frame stored exactly once,
  no stray thumbnail or temporary file, a store that opens clean;
* a second writer is refused (exit 2, naming the first one's pid) or waits with `--wait`;
* a reader searches while a writer writes.
"""

from __future__ import annotations

import json
import os
import random
import re
import signal
import sqlite3
import subprocess
import sys
import time
from collections import Counter
from functools import partial
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from ravenmem.fsio import is_temp_file
from ravenmem.ingest.keyframes import KeyframeConfig, Keyframer
from ravenmem.ingest.tum import TumSource
from ravenmem.types import Frame
from tests.cli.helpers import ForkedCli, run_cli

REPO = Path(__file__).resolve().parents[2]
HERE = Path(__file__).resolve().parent
# stride 10 keeps 72 of the 720 posed frames (several seconds of embedding on 2 cores); the
# novelty rule is on (threshold 1.0 drops nothing) so resuming replays it on stored embeddings
SPEC = "stride=10,max_similarity=1.0"
EMBEDDER = "offline:tiles=1:res=128"  # the real offline model, at half the default's cost


def env() -> dict[str, str]:
    return dict(os.environ, PYTHONPATH=os.pathsep.join([str(REPO / "src"), str(REPO)]))


rm = partial(run_cli, timeout=600)


def start(*args: str) -> subprocess.Popen[str]:
    return subprocess.Popen(
        [sys.executable, "-m", "ravenmem.cli.main", *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env(),
    )


def ingest_args(tum: Path, mem: Path, spec: str = SPEC, *more: str) -> list[str]:
    return [
        "ingest",
        str(tum),
        "--memory",
        str(mem),
        "--no-ocr",
        "--keyframes",
        spec,
        "--embedder",
        EMBEDDER,
        "--json",
        *more,
    ]


def stored_count(mem: Path) -> int:
    """Memories committed so far, read as any SQLite reader would (never blocks the writer)."""
    db = mem / "store.sqlite"
    if not db.exists():
        return 0
    try:
        with sqlite3.connect(f"file:{db}?mode=ro", uri=True, timeout=5) as conn:
            return int(conn.execute("SELECT COUNT(*) FROM memories").fetchone()[0])
    except sqlite3.Error:
        return 0


def wait_for(cond, proc: subprocess.Popen[str], what: str, limit: float = 300) -> None:  # type: ignore[no-untyped-def]
    deadline = time.time() + limit
    while not cond():
        if proc.poll() is not None:
            pytest.fail(f"the writer exited ({proc.returncode}) before {what}: {proc.stderr.read()}")  # type: ignore[union-attr]
        if time.time() > deadline:
            proc.kill()
            pytest.fail(f"timed out waiting for {what}")
        time.sleep(0.05)


def all_memories(cli: ForkedCli, mem: Path) -> list[dict]:  # type: ignore[type-arg]
    """Every memory, as `search --time start --json` lists them (forked by the test's driver)."""
    r = cli("search", "--time", "start", "-k", "1000", "--memory", str(mem), "--json", timeout=600)
    assert r.returncode == 0, r.stderr
    return json.loads(r.stdout)["results"]


def expected_frames(tum: Path, spec: str) -> list[int]:
    """The frame indices one uninterrupted run keeps: the posed frames the keyframe rules pass
    (the novelty threshold of 1.0 drops none of these distinct camera images). The poses are
    matched as the source matches them; the images are not decoded (the cheap rules never look
    at them, and every image of the recording reads: 720 decodes took ~3 s a call)."""
    src, kf = TumSource(tum), Keyframer(KeyframeConfig.from_spec(spec))
    blank = np.zeros((1, 1, 3), np.uint8)
    out = []
    for i, (t, _) in enumerate(src.entries):
        pose = src.track.match(t, src.pose_match, src.max_gap)
        if not isinstance(pose, str) and kf.pre(Frame(image=blank, t=t, pose=pose, index=i)) is None:
            out.append(i)
    return out


def assert_clean(mem: Path, memories: list[dict]) -> None:  # type: ignore[type-arg]
    """Every thumbnail belongs to a memory and every memory's thumbnail exists; no temp files,
    no journal left."""
    on_disk = {p.name for p in (mem / "thumbs").iterdir()}
    referenced = {Path(m["image"]).name for m in memories}
    assert on_disk == referenced, (sorted(on_disk - referenced), sorted(referenced - on_disk))
    leftovers = [p for p in [*mem.iterdir(), *(mem / "thumbs").iterdir()] if is_temp_file(p)]
    assert leftovers == []
    with sqlite3.connect(mem / "store.sqlite") as conn:
        assert conn.execute("PRAGMA integrity_check").fetchone()[0] == "ok"


def test_kill_9_then_same_command_stores_every_frame_once(
    tmp_path: Path, tum_path: Path, forked_cli: ForkedCli
) -> None:
    mem = tmp_path / "desk.mem"
    seed = random.randrange(10**6)
    rng = random.Random(seed)
    # a random moment: after a random number of the 9 batches of 8 is stored (leaving at least
    # two to go), plus a random fraction of the next batch's work
    target, delay = 8 * rng.randint(1, 7), rng.uniform(0.0, 0.3)
    args = ingest_args(tum_path, mem, SPEC, "--batch-size", "8")
    proc = start(*args)
    wait_for(lambda: stored_count(mem) >= target, proc, f"{target} frames were stored")
    time.sleep(delay)
    proc.send_signal(signal.SIGKILL)
    proc.wait(30)
    before = stored_count(mem)
    assert proc.returncode == -signal.SIGKILL, f"the ingest finished before the kill (seed {seed})"

    r = rm(*args)
    assert r.returncode == 0, r.stderr
    rep = json.loads(r.stdout)
    want = expected_frames(tum_path, SPEC)
    assert len(want) == 72
    assert rep["skipped"]["already in memory"] == before, f"seed {seed}"
    assert rep["kept"] == len(want) - before and rep["memories_total"] == len(want)

    memories = all_memories(forked_cli, mem)
    counts = Counter((m["source"], m["frame_index"]) for m in memories)
    assert len({s for s, _ in counts}) == 1 and next(iter(counts))[0].startswith("tum:tum_fr1_rpy@")
    assert sorted(i for _, i in counts) == want, f"seed {seed}: {target} stored + {delay:.2f} s"
    assert max(counts.values()) == 1
    assert_clean(mem, memories)


def test_thumbnails_of_a_batch_killed_before_commit_are_removed(
    tmp_path: Path, tum_path: Path, forked_cli: ForkedCli
) -> None:
    """Deterministic: the writer dies inside the store's add, after writing the thumbnails."""
    mem = tmp_path / "m.mem"
    spec = "stride=60"
    args = ingest_args(tum_path, mem, spec, "--batch-size", "4")
    crash = subprocess.run(
        [sys.executable, str(HERE / "crash_ingest.py"), "2", *args],
        capture_output=True,
        text=True,
        env=env(),
        timeout=600,
    )
    assert crash.returncode == -signal.SIGKILL, crash.stderr
    assert stored_count(mem) == 4  # the first batch; the second died before its commit
    thumbs = list((mem / "thumbs").glob("*.jpg"))
    assert len(thumbs) == 8 and list(mem.glob("pending-thumbs-*.json"))

    r = rm(*args)
    assert r.returncode == 0, r.stderr
    memories = all_memories(forked_cli, mem)
    assert sorted(m["frame_index"] for m in memories) == expected_frames(tum_path, spec)
    assert_clean(mem, memories)
    assert not list(mem.glob("pending-thumbs-*.json"))


def test_clean_up_removes_only_ravenmem_leftovers(tmp_path: Path, tum_path: Path) -> None:
    mem = tmp_path / "m.mem"
    args = ingest_args(tum_path, mem, "stride=240")
    assert rm(*args).returncode == 0
    old = time.time() - 60
    # what a writer killed while writing a thumbnail leaves: the batch's journal, a thumbnail
    # written before it, the temporary file of the one it was writing
    cut = mem / "thumbs" / "000000000000002_abcdef02.jpg"
    journal = mem / "pending-thumbs-00112233aabb.json"
    journal.write_text(json.dumps({"thumbs": [[f"thumbs/{cut.name}", "tum:x@0", 5, 2.5]]}))
    stale = [
        mem / ".memory.json.0123456789ab.tmp",
        mem / "thumbs" / f".{cut.name}.ba9876543210.tmp",
        cut,
        mem / ".pending-thumbs-445566ccddee.json.0123456789ab.tmp",
    ]
    foreign = [
        mem / "notes.txt",
        mem / ".notes.tmp",  # not a name ravenmem makes
        mem / ".memory.json.XYZ.tmp",
        mem / "thumbs" / "holiday.jpg",
        mem / "thumbs" / "000000000000001_abcdef01.jpg",  # thumbnail-like, but no journal lists it
    ]
    for p in stale + foreign:
        p.write_bytes(b"x")
        os.utime(p, (old, old))
    # the temporary files of a thumbnail, the manifest and a journal are fresh: the writer was
    # killed a moment ago and the same command runs again at once (the next writer holds the
    # writer lock, so no other process can be writing these); "fresh" whatever this run's start-up
    # time: written a minute from now
    soon = time.time() + 60
    for p in (stale[0], stale[1], stale[3]):
        os.utime(p, (soon, soon))
    # a temporary file another process is writing right now (it holds the lock atomic_open takes)
    busy = mem / ".index.faiss.00aa11bb22cc.tmp"
    holder = subprocess.Popen(
        [
            sys.executable,
            "-c",
            "import fcntl,os,sys,time; f=open(sys.argv[1],'wb'); os.utime(sys.argv[1],(0,0)); "
            "fcntl.flock(f, fcntl.LOCK_EX); print('locked', flush=True); time.sleep(600)",
            str(busy),
        ],
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert holder.stdout is not None and holder.stdout.readline().strip() == "locked"
        r = rm(*args)
        assert r.returncode == 0, r.stderr
        assert json.loads(r.stdout)["skipped"]["already in memory"] == 3
        assert [p for p in [*stale, journal] if p.exists()] == []
        assert [p for p in foreign if not p.exists()] == []
        assert busy.exists()
    finally:
        holder.kill()
        holder.wait()


def gated_tum(folder: Path, n: int = 12) -> Path:
    """A TUM folder of n small images and, last, `rgb/gate.png`: a FIFO. An ingest of it stores
    its n frames, then blocks reading the gate (holding the writer lock) until `open_gate`."""
    (folder / "rgb").mkdir(parents=True)
    rng = np.random.default_rng(0)
    rgb, gt = [], []
    for i in range(n + 1):
        t = 1000.0 + 0.1 * i
        name = f"rgb/{i:03d}.png" if i < n else "rgb/gate.png"
        if i < n:
            Image.fromarray(rng.integers(0, 256, (48, 64, 3), dtype=np.uint8)).save(folder / name)
        rgb.append(f"{t:.6f} {name}")
        gt.append(f"{t:.6f} {0.1 * i:.3f} 0 0 0 0 0 1")
    (folder / "rgb.txt").write_text("\n".join(rgb) + "\n")
    (folder / "groundtruth.txt").write_text("\n".join(gt) + "\n")
    os.mkfifo(folder / "rgb" / "gate.png")
    return folder


def open_gate(folder: Path) -> None:
    """Feed the blocked reader a real image; from now on the gate is a plain file."""
    gate = folder / "rgb" / "gate.png"
    deadline = time.time() + 120
    while True:
        try:
            fd = os.open(gate, os.O_WRONLY | os.O_NONBLOCK)  # fails until the ingest opened it
            break
        except OSError:
            if time.time() > deadline:
                pytest.fail("the ingest never reached the gate")
            time.sleep(0.05)
    Image.fromarray(np.full((48, 64, 3), 200, np.uint8)).save(folder / "real.png")
    data = (folder / "real.png").read_bytes()
    os.replace(folder / "real.png", gate)  # the next reader gets a plain file
    os.set_blocking(fd, True)
    os.write(fd, data)
    os.close(fd)


def test_second_writer_is_refused_or_waits(tmp_path: Path) -> None:
    rec = gated_tum(tmp_path / "rec")
    mem = tmp_path / "m.mem"
    first = start(*ingest_args(rec, mem, "all", "--batch-size", "4"))
    lock = mem / "writer.lock"

    def holder_pid() -> int | None:
        try:
            return int(json.loads(lock.read_text())["pid"])
        except (OSError, ValueError, KeyError):
            return None

    wait_for(lambda: holder_pid() == first.pid and stored_count(mem) == 12, first, "12 frames were stored")
    other = rm(*ingest_args(rec, mem, "all"), timeout=300)
    assert other.returncode == 2, other.stderr
    err = other.stderr.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err, err
    assert f"pid {first.pid}" in err and "ingest" in err and "--wait" in err

    waiter = start(*ingest_args(rec, mem, "all", "--wait"))
    time.sleep(3)
    assert waiter.poll() is None, "--wait did not wait"
    assert first.poll() is None
    open_gate(rec)
    out, err = first.communicate(timeout=600)
    assert first.returncode == 0, err
    assert json.loads(out)["kept"] == 13
    out, err = waiter.communicate(timeout=600)
    assert waiter.returncode == 0, err
    rep = json.loads(out)
    assert rep["kept"] == 0 and rep["skipped"]["already in memory"] == 13 == rep["memories_total"]


def test_reader_searches_while_a_writer_writes(tmp_path: Path) -> None:
    rec = gated_tum(tmp_path / "rec")
    mem = tmp_path / "m.mem"
    writer = start(*ingest_args(rec, mem, "all", "--batch-size", "4"))
    try:
        wait_for(lambda: stored_count(mem) == 12, writer, "12 frames were stored")
        info = rm("info", "--memory", str(mem), "--json", timeout=300)
        assert info.returncode == 0, info.stderr
        assert json.loads(info.stdout)["memories"] == 12
        found = rm("search", "--position", "0.5,0", "-k", "3", "--memory", str(mem), "--json", timeout=300)
        assert found.returncode == 0, found.stderr
        xs = [round(h["x"], 3) for h in json.loads(found.stdout)["results"]]
        assert xs[0] == 0.5 and sorted(xs[1:]) == [0.4, 0.6]
        assert writer.poll() is None  # still writing (blocked at the gate, holding the lock)
    finally:
        open_gate(rec)
    out, err = writer.communicate(timeout=600)
    assert writer.returncode == 0, err
    assert json.loads(out)["memories_total"] == 13


def test_progress_bar_has_a_total_and_eta_on_a_terminal(tmp_path: Path, tum_path: Path) -> None:
    """On a terminal the bar counts frames seen against the recording's 723 and gives an ETA;
    the summary line gives the keyframe ratio."""
    import fcntl
    import pty
    import struct
    import termios
    import threading

    master, slave = pty.openpty()
    fcntl.ioctl(slave, termios.TIOCSWINSZ, struct.pack("HHHH", 24, 120, 0, 0))  # a 120-column terminal
    args = ingest_args(tum_path, tmp_path / "m.mem", "stride=240")[:-1]  # the human summary
    proc = subprocess.Popen(
        [sys.executable, "-m", "ravenmem.cli.main", *args],
        stdin=subprocess.DEVNULL,
        stdout=subprocess.PIPE,
        stderr=slave,
        text=True,
        env=env(),
    )
    os.close(slave)
    chunks: list[bytes] = []

    def drain() -> None:
        while True:
            try:
                data = os.read(master, 4096)
            except OSError:
                return
            if not data:
                return
            chunks.append(data)

    reader = threading.Thread(target=drain, daemon=True)
    reader.start()
    out, _ = proc.communicate(timeout=600)
    reader.join(10)
    os.close(master)
    bar = b"".join(chunks).decode("utf-8", "replace")
    assert proc.returncode == 0, bar
    assert re.search(r"\d+/723 \[", bar), bar[-500:]
    assert re.search(r"<\d\d:\d\d", bar), bar[-500:]  # the remaining time
    assert "723/723" in bar
    assert re.search(r"723 frames seen, 3 kept, 1 in 241\.0", out), out
