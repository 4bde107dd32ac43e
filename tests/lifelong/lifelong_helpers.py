"""Small memories for the forgetting and consolidation tests, and the command run as users run it."""

from __future__ import annotations

import json
import os
import sqlite3
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np

import ravenmem
from ravenmem.fsio import is_temp_file
from ravenmem.types import Frame, Pose
from tests.cli.helpers import run_cli
from tests.conftest import COLORS, ColorEmbedder

REPO = Path(__file__).resolve().parents[2]
T0 = 1_700_000_000.0
# runs of one colour seen from nearly one place: near-duplicates; runs 5 m apart
RUNS = ["red", "green", "blue", "red", "yellow", "white"]
PER_RUN = 5


def env() -> dict[str, str]:
    return dict(os.environ, PYTHONPATH=os.pathsep.join([str(REPO / "src"), str(REPO)]))


rm = partial(run_cli, timeout=300)


def rm_json(*args: str) -> dict[str, Any]:
    r = rm(*args, "--json")
    assert r.returncode == 0, r.stderr[-3000:]
    return json.loads(r.stdout)  # type: ignore[no-any-return]


def tinted(colour: str, seed: int, h: int = 24, w: int = 32) -> np.ndarray:
    """A solid colour with a little noise: near-duplicates of one colour are alike, not equal."""
    rng = np.random.default_rng(seed)
    base = np.array(COLORS[colour], np.float32)
    img = np.clip(base + rng.normal(0, 12, (h, w, 3)), 0, 255)
    return img.astype(np.uint8)


def run_frames(runs: list[str] = RUNS, per_run: int = PER_RUN, spacing: float = 5.0) -> list[Frame]:
    """Run r is colour runs[r], taken 10 s apart around x = spacing * r (0.05 m steps), y = 0."""
    frames = []
    for r, colour in enumerate(runs):
        for j in range(per_run):
            i = r * per_run + j
            frames.append(
                Frame(
                    image=tinted(colour, i),
                    t=T0 + 10 * i,
                    pose=Pose(spacing * r + 0.05 * j, 0.0, 0.5),
                    source="walk",
                    index=i,
                )
            )
    return frames


def make_runs(
    path: Path, runs: list[str] = RUNS, per_run: int = PER_RUN, thumb_size: int = 16, spacing: float = 5.0
) -> Path:
    with ravenmem.create(path, embedder=ColorEmbedder(), ocr=False, thumb_size=thumb_size) as m:
        frames = run_frames(runs, per_run, spacing)
        for s in range(0, len(frames), 500):
            m.add_frames(frames[s : s + 500])
    return path


def records(path: Path) -> list[Any]:
    """Every stored memory, read by a fresh reader (no writer lock, no recovery)."""
    with ravenmem.open(path) as m:
        return m.all_records()


def thumbs_on_disk(path: Path) -> set[str]:
    return {f"thumbs/{p.name}" for p in (path / "thumbs").iterdir() if not is_temp_file(p)}


def assert_consistent(path: Path, why: str = "") -> None:
    """After a writer opened the memory: every thumbnail belongs to a stored memory and every
    stored memory's thumbnail exists; no journal, no temporary file; SQLite intact. `why`
    (e.g. a random test's seed) starts every failure message."""
    recs = records(path)
    referenced = {r.image_path for r in recs}
    assert thumbs_on_disk(path) == referenced, f"{why}: {thumbs_on_disk(path) ^ referenced}"
    journals = [p.name for p in path.glob("pending-thumbs-*.json")]
    assert not journals, f"{why}: journals left {journals}"
    temps = [p.name for p in [*path.iterdir(), *(path / "thumbs").iterdir()] if is_temp_file(p)]
    assert not temps, f"{why}: temporary files left {temps}"
    with sqlite3.connect(path / "store.sqlite") as conn:
        assert conn.execute("PRAGMA integrity_check").fetchone()[0] == "ok", why


def writer_open(path: Path) -> None:
    """What the next writer does first: take the lock and clean up after a killed one."""
    with ravenmem.open(path, writable=True):
        pass


def hits(path: Path) -> list[dict[str, Any]]:
    """Every memory as the search tools report it (chronological)."""
    return rm_json("search", "--time", "start", "-k", "1000", "--memory", str(path))["results"]  # type: ignore[no-any-return]
