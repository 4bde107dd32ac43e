"""Inputs that would have destroyed stored data: an absurd transform given to `align --apply`,
and a damaged store row that used to brick the memory at the next write. Each is refused (or
set aside) in one line, and the memory keeps what it held and takes writes afterwards."""

from __future__ import annotations

import json
import sqlite3
from pathlib import Path

import pytest

import ravenmem
from ravenmem.types import Pose
from tests.cli.helpers import T0, make_memory
from tests.conftest import ColorEmbedder, solid
from tests.hardening.conftest import one_line_error, snapshot
from tests.hardening.runner import Driver

CACHES = ("writer.lock", "columns.cache", "index.faiss")  # rebuilt from the store; the lock holds a pid


def _data(mem: Path) -> dict[str, tuple[int, int, str]]:
    """The memory's files except its caches and its lock (a writer may save those)."""
    return {k: v for k, v in snapshot(mem).items() if k not in CACHES}


def _poses(mem: Path) -> list[tuple[float, float, float, float]]:
    with ravenmem.open(mem) as m:
        return [
            (h.memory.pose.x, h.memory.pose.y, h.memory.pose.z, h.memory.pose.yaw)
            for h in m.search_time("start", k=100)
        ]


# ---------------------------------------------------------------- align --apply
@pytest.mark.parametrize(
    "transform,names",
    [
        ("0,0,0,1e308", "out of range"),  # 1e308 degrees: every pose turned to a random heading
        ("0,0,0,nan", "--transform"),
        ("1e308,0,0,0", "out of range"),
        ("0,0,-inf,0", "--transform"),
        ("1.5e7,0,0,0", "would move memory"),  # a shift a map can take, but not these poses
    ],
)
def test_align_apply_refuses_a_transform_that_would_ruin_the_poses(
    tmp_path: Path, driver: Driver, transform: str, names: str
) -> None:
    a, b = make_memory(tmp_path / "a.mem"), make_memory(tmp_path / "b.mem")
    before, poses = _data(a), _poses(a)
    r = driver.run(["align", "--from", str(a), "--to", str(b), "--transform", transform, "--apply"])
    assert names in one_line_error(r)
    assert _data(a) == before and _poses(a) == poses


def test_align_apply_still_moves_the_poses_by_a_sane_transform(tmp_path: Path, driver: Driver) -> None:
    a, b = make_memory(tmp_path / "a.mem"), make_memory(tmp_path / "b.mem")
    r = driver.run(
        ["align", "--from", str(a), "--to", str(b), "--transform", "10,0,0,0", "--apply", "--json"]
    )
    assert r["rc"] == 0, r
    assert [p[0] for p in _poses(a)] == pytest.approx([10.0, 11.0, 12.0, 13.0, 14.0])


# ---------------------------------------------------------------- a damaged store row
def _damage(mem: Path, column: str, value: object) -> None:
    """What a disk error, another program or a writer from before the checks leaves: one row
    whose position is not a number (SQLite keeps a NaN as NULL, which NOT NULL refuses: a NaN
    that reaches the file is the text 'nan', an infinity, or something else again)."""
    db = sqlite3.connect(mem / "store.sqlite")
    db.execute(f"UPDATE memories SET {column} = ? WHERE id = 3", (value,))
    db.commit()
    db.close()
    for cache in ("columns.cache",):  # a cache saved before the damage would hide it
        (mem / cache).unlink(missing_ok=True)


@pytest.mark.parametrize(
    "column,value",
    [("x", "nan"), ("y", float("inf")), ("z", float("-inf")), ("t", "yesterday"), ("yaw", b"\x00")],
)
def test_a_damaged_row_never_bricks_the_memory_at_the_next_write(
    tmp_path: Path, driver: Driver, column: str, value: object
) -> None:
    mem = make_memory(tmp_path / "m.mem")
    _damage(mem, column, value)
    for args in (
        ["--time", "start", "-k", "9"],
        ["--position", "1,2", "-k", "9"],
    ):  # a reader: refused in one line
        r = driver.run(["search", "-m", str(mem), *args, "--json"])
        if r["rc"] != 0:  # a listing that holds the damaged row is refused, not a traceback
            assert "stored memory 3 is damaged" in one_line_error(r)
    for _ in range(2):  # the second write finds the memory as the first left it
        r = driver.run(
            [
                "ingest",
                str(Path(__file__).parents[2] / "examples" / "tum_desk"),
                "-m",
                str(mem),
                "--embedder",
                "test-color",
                "--json",
            ]
        )
        assert r["rc"] == 0 and "Traceback" not in str(r["stderr"]), r
    info = driver.run(["info", "-m", str(mem), "--json"])
    assert info["rc"] == 0, info
    n = json.loads(str(info["stdout"]))["memories"]
    r = driver.run(["search", "-m", str(mem), "--time", "start", "-k", "100", "--json"])
    ids = {h["id"] for h in json.loads(str(r["stdout"]))["results"]}
    assert len(ids) == n > 4 and {1, 2, 4, 5} <= ids and 3 not in ids  # the ingest added some
    r = driver.run(["search", "-m", str(mem), "--position", "1,2", "--json"])
    assert r["rc"] == 0 and json.loads(str(r["stdout"]))["results"][0]["id"] == 2, r
    with sqlite3.connect(mem / "store.sqlite") as db:  # kept for a person, as it was
        assert [row[0] for row in db.execute("SELECT id FROM memories_aside")] == [3]
    with ravenmem.open(mem, embedder=ColorEmbedder()) as m:
        m.add(solid("blue"), Pose(0.0, 0.0), T0 + 999)
        assert m.count() == n + 1


# ---------------------------------------------------------------- a garbage sidecar
def test_a_garbage_groups_table_is_set_aside_and_the_ingest_goes_on(tmp_path: Path, driver: Driver) -> None:
    mem = make_memory(tmp_path / "m.mem")
    garbage = bytes(range(256)) * 20
    (mem / "lifelong.sqlite").write_bytes(garbage)
    tum = str(Path(__file__).parents[2] / "examples" / "tum_desk")
    r = driver.run(["ingest", tum, "-m", str(mem), "--embedder", "test-color", "--json"])
    assert r["rc"] == 0 and "Traceback" not in str(r["stderr"]), r
    assert "set aside" in str(r["stderr"])
    assert (mem / "lifelong.sqlite.aside").read_bytes() == garbage  # kept for a person, as it was
    info = driver.run(["info", "-m", str(mem), "--json"])
    assert info["rc"] == 0 and json.loads(str(info["stdout"]))["memories"] > 5, info
    r = driver.run(["consolidate", "-m", str(mem), "--budget", "3", "--json"])  # the new table works
    assert r["rc"] == 0, r
