"""`ravenmem forget` as users run it: each selector, the report, dry runs, errors, the lock."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

import ravenmem
from ravenmem.errors import InputError
from ravenmem.types import Frame, Pose
from tests.cli.helpers import assert_one_line_error
from tests.conftest import ColorEmbedder
from tests.lifelong.lifelong_helpers import (
    T0,
    assert_consistent,
    make_runs,
    records,
    rm,
    rm_json,
    thumbs_on_disk,
    tinted,
)


@pytest.fixture(scope="module")
def template(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return make_runs(tmp_path_factory.mktemp("forget") / "walk.mem")


@pytest.fixture
def walk(template: Path, tmp_path: Path) -> Path:
    return Path(shutil.copytree(template, tmp_path / "walk.mem"))


def by_id(path: Path) -> dict[int, object]:
    return {r.id: r for r in records(path)}


def test_before_removes_memories_thumbnails_and_reports_them(walk: Path) -> None:
    before = by_id(walk)
    gone = [r for r in before.values() if r.t <= T0 + 45]  # type: ignore[attr-defined]
    sizes = sum((walk / r.image_path).stat().st_size for r in gone)  # type: ignore[attr-defined]
    out = rm_json("forget", "--memory", str(walk), "--before", "+45")
    assert out["removed"] == 5 == len(gone) and out["memories_left"] == 25
    assert (out["t_first"], out["t_last"]) == (T0, T0 + 40)
    assert out["first_time"].startswith("2023-11-14T22:13:20") and out["thumbnails"] == 5
    assert out["thumbnail_bytes"] == sizes and out["bytes_freed"] == sizes + out["store_bytes_est"] > sizes
    after = by_id(walk)
    assert set(after) == set(before) - {r.id for r in gone}  # type: ignore[attr-defined]
    assert not any((walk / r.image_path).exists() for r in gone)  # type: ignore[attr-defined]
    assert_consistent(walk)
    with ravenmem.open(walk) as m:
        assert m.time_span()[0] == T0 + 50  # the first memory left
        assert all(h.memory.t > T0 + 45 for h in m.search_time("start", k=100))
    # search results no longer know them, and an image search by a forgotten id says so
    r = rm("search", "--like", str(gone[0].id), "--memory", str(walk))  # type: ignore[attr-defined]
    assert "no such memory" in assert_one_line_error(r)


def test_after_region_ids_and_combinations(walk: Path) -> None:
    recs = by_id(walk)
    # --region: run 2 sits around x = 10..10.2, y = 0
    out = rm_json("forget", "-m", str(walk), "--region", "10.1,0,0.5")
    assert out["removed"] == 5
    assert all(not 9.5 < r.pose.x < 10.5 for r in records(walk))
    # --before and --region together: only memories matching both
    out = rm_json("forget", "-m", str(walk), "--before", "+100", "--region", "0,0,30")
    assert out["removed"] == 10 - 0  # runs 0 and 1 (t <= +90), run 2 already gone
    assert min(r.t for r in records(walk)) == T0 + 150
    # --after alone; offsets count from the first memory this memory ever held (T0), not from
    # the first one left (T0 + 150 now): the same command run again means the same instant
    out = rm_json("forget", "-m", str(walk), "--after", "+270")
    assert out["removed"] == 3 and max(r.t for r in records(walk)) == T0 + 260
    # --ids with ranges, some unknown, some not matching the other selector
    left = sorted(r.id for r in records(walk))
    wanted = f"{left[0]}-{left[2]},{left[-1]},9999"
    out = rm_json("forget", "-m", str(walk), "--ids", wanted, "--after", "+0")
    assert out["removed"] == 4 and out["unknown_ids"] == 1
    assert sorted(r.id for r in records(walk)) == left[3:-1]
    assert len(recs) - sum(1 for _ in records(walk)) == 5 + 10 + 3 + 4
    assert_consistent(walk)


def test_dry_run_reports_and_changes_nothing(walk: Path) -> None:
    files = {p: p.stat().st_size for p in walk.rglob("*") if p.is_file() and p.name != "writer.lock"}
    out = rm_json("forget", "-m", str(walk), "--before", "+95", "--dry-run")
    assert out["dry_run"] is True and out["removed"] == 10 and out["thumbnails"] == 10
    assert out["memories_left"] == 20
    assert len(records(walk)) == 30 and len(thumbs_on_disk(walk)) == 30
    assert {p for p in walk.rglob("*") if p.is_file() and p.name != "writer.lock"} >= set(files)
    r = rm("forget", "-m", str(walk), "--before", "+95", "--dry-run")
    assert r.returncode == 0 and r.stdout.startswith("would forget 10 memories")


def test_an_empty_selection_is_not_an_error(walk: Path) -> None:
    out = rm_json("forget", "-m", str(walk), "--before", "1999-01-01T00:00:00")
    assert out["removed"] == 0 and out["t_first"] is None and out["memories_left"] == 30
    r = rm("forget", "-m", str(walk), "--ids", "4000")
    assert r.returncode == 0 and r.stdout.startswith("forgot 0 memories") and "1 of the given ids" in r.stdout
    assert len(records(walk)) == 30


@pytest.mark.parametrize(
    ("args", "says"),
    [
        ([], "say what to forget"),
        (["--before", "yesterday-ish"], "cannot read a time"),
        (["--after", "nan"], "time"),
        (["--region", "1,2"], "--region"),
        (["--region", "1,2,nan"], "--region"),
        (["--region", "1,2,0"], "near must be finite"),
        (["--ids", "x"], "--ids"),
        (["--ids", "5-3"], "--ids"),
        (["--ids", "-1"], "--ids"),
        (["--ids", ","], "no id given"),
    ],
)
def test_bad_input_is_one_line_and_loses_nothing(walk: Path, args: list[str], says: str) -> None:
    line = assert_one_line_error(rm("forget", "-m", str(walk), *args))
    assert says in line
    assert len(records(walk)) == 30 and len(thumbs_on_disk(walk)) == 30


def test_a_missing_memory_and_a_busy_writer_are_one_line_errors(walk: Path, tmp_path: Path) -> None:
    line = assert_one_line_error(rm("forget", "-m", str(tmp_path / "nope.mem"), "--before", "+5"))
    assert "does not exist" in line
    with ravenmem.open(walk, writable=True):
        line = assert_one_line_error(rm("forget", "-m", str(walk), "--before", "+5"))
        assert "is being written by" in line
        assert rm_json("forget", "-m", str(walk), "--before", "+5", "--dry-run")["removed"] == 1
    assert len(records(walk)) == 30


def test_python_api_and_ids_are_never_reused(walk: Path) -> None:
    with ravenmem.open(walk, embedder=ColorEmbedder()) as m:
        with pytest.raises(InputError, match="say what to forget"):
            m.forget()
        newest = max(r.id for r in m.all_records())
        rep = m.forget(ids=[newest, newest - 1])
        assert rep.removed == 2 and m.is_writer and m.count() == 28
        (new_id,) = m.add_frames([Frame(image=tinted("red", 99), t=T0 + 999, pose=Pose(0, 0, 0.5), index=99)])
        assert new_id > newest  # a forgotten id never comes back as another memory
        assert m.forget(region=(0.0, 0.0, 0.01), before="+5", dry_run=True).removed == 1
        assert m.forget(ids=np.array([new_id])).removed == 1
        with pytest.raises(InputError, match="ids"):
            m.forget(ids=[1.5])  # type: ignore[list-item]
    assert_consistent(walk)


def test_memories_without_thumbnails_keep_their_original_files(tmp_path: Path) -> None:
    """A memory built with thumb_size=0 stores the original frames' paths: never deleted."""
    originals = []
    for i in range(3):
        p = tmp_path / f"frame{i}.png"
        Image.fromarray(tinted("blue", i)).save(p)
        originals.append(p)
    with ravenmem.create(tmp_path / "ext.mem", embedder=ColorEmbedder(), ocr=False, thumb_size=0) as m:
        m.add_frames(
            [
                Frame(image=tinted("blue", i), t=T0 + i, pose=Pose(0, 0, 0), index=i, path=str(p))
                for i, p in enumerate(originals)
            ]
        )
    out = rm_json("forget", "-m", str(tmp_path / "ext.mem"), "--before", "+5")
    assert out["removed"] == 3 and out["thumbnails"] == 0 and out["thumbnail_bytes"] == 0
    assert all(p.exists() for p in originals)


def test_a_reader_opened_before_forget_keeps_answering(walk: Path) -> None:
    """A read-only service or `ravenmem mcp` runs beside the writer: its index still holds the
    memories another process forgot. Its searches skip them instead of failing."""
    with ravenmem.open(walk, embedder=ColorEmbedder()) as reader:
        assert len(reader.search_position(0.1, 0.0, k=3)) == 3
        gone = {r.id for r in records(walk) if r.pose.x < 2.5}  # the first red run
        out = rm_json("forget", "--memory", str(walk), "--region", "0,0,2.5")
        assert out["removed"] == len(gone) == 5
        near = reader.search_position(0.1, 0.0, k=3)
        red = reader.search_text("red", k=3)
        image = reader.search_image(tinted("red", 99), k=3)
        w = reader.last_seen("red")
        shown = [h.memory.id for p in w.places for h in p.sightings]  # read while the memory is open
    assert len(near) == 3 and not {h.memory.id for h in near + red + image} & gone
    assert red and red[0].memory.pose.x == pytest.approx(15, abs=0.3)  # the red run that is left
    assert w.places and shown and not set(shown) & gone
