"""`ravenmem consolidate`: near-duplicate neighbours merge into a representative that keeps
their span and count; budgets, similarity, places and revisits; what the tools then show."""

from __future__ import annotations

import math
import shutil
from pathlib import Path

import numpy as np
import pytest

import ravenmem
from ravenmem.memory.lifelong.consolidate import plan
from ravenmem.timeparse import fmt_time
from tests.cli.helpers import assert_one_line_error
from tests.conftest import ColorEmbedder
from tests.lifelong.lifelong_helpers import (
    PER_RUN,
    RUNS,
    T0,
    assert_consistent,
    hits,
    make_runs,
    records,
    rm,
    rm_json,
    thumbs_on_disk,
)


@pytest.fixture(scope="module")
def template(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return make_runs(tmp_path_factory.mktemp("consolidate") / "walk.mem")


@pytest.fixture
def walk(template: Path, tmp_path: Path) -> Path:
    return Path(shutil.copytree(template, tmp_path / "walk.mem"))


def test_near_duplicates_of_one_place_merge_and_keep_span_and_count(walk: Path) -> None:
    before = records(walk)
    out = rm_json("consolidate", "-m", str(walk), "--max-similarity", "0.95")
    assert (out["before"], out["after"], out["merged"], out["groups"]) == (30, 6, 24, 6)
    assert out["represented"] == 30 and out["lowest_similarity"] > 0.95 and out["thumbnails"] == 24
    shown = hits(walk)
    assert len(shown) == 6
    for r, h in enumerate(shown):  # one representative per run, standing for the whole run
        run = before[r * PER_RUN : (r + 1) * PER_RUN]
        assert h["id"] in {m.id for m in run} and h["count"] == PER_RUN
        assert (h["first_t"], h["last_t"]) == (run[0].t, run[-1].t)
        assert h["first_time"] < h["time"] <= h["last_time"] or h["time"] == h["first_time"]
        assert (walk / Path(h["image"]).relative_to(walk)).exists()
    assert_consistent(walk)
    info = rm_json("info", "-m", str(walk))
    assert (info["memories"], info["consolidated"], info["memories_represented"]) == (6, 6, 30)
    with ravenmem.open(walk) as m:
        assert m.time_span() == (T0, T0 + 290)
        assert m.group(shown[0]["id"]) == (PER_RUN, T0, T0 + 40)
    with ravenmem.open(walk, embedder=ColorEmbedder()) as m:
        h = m.search_text("blue", k=1)[0]
        assert h.count == PER_RUN and h.span == (T0 + 100, T0 + 140)
        assert h.memory.pose.x == pytest.approx(10, abs=0.3)


def test_a_budget_merges_the_most_similar_neighbours_first(walk: Path) -> None:
    out = rm_json("consolidate", "-m", str(walk), "--budget", "12")
    assert out["after"] == 12 and out["budget_met"] is True and out["represented"] == 30
    shown = hits(walk)
    assert sum(h.get("count", 1) for h in shown) == 30
    # spans tile the timeline: consecutive, never overlapping
    spans = [(h.get("first_t", h["t"]), h.get("last_t", h["t"])) for h in shown]
    # runs 5 m apart never merge across places (max-distance 1 m): a span stays in its run
    run_len = 10 * PER_RUN
    assert all((a - T0) // run_len == (b - T0) // run_len for a, b in spans)
    assert len({(a - T0) // run_len for a, _ in spans}) == len(RUNS)
    assert all(a[1] < b[0] for a, b in zip(spans, spans[1:]))
    assert spans[0][0] == T0 and spans[-1][1] == T0 + 290
    # consolidating again accumulates counts and spans
    out = rm_json("consolidate", "-m", str(walk), "--budget", "6")
    assert out["after"] == 6 and out["represented"] == 30
    assert [h["count"] for h in hits(walk)] == [PER_RUN] * 6
    assert_consistent(walk)


def test_a_budget_out_of_reach_says_so(walk: Path) -> None:
    r = rm("consolidate", "-m", str(walk), "--budget", "3")
    assert r.returncode == 0 and "30 -> 6 memories" in r.stdout and "budget of 3 was not reached" in r.stdout
    out = rm_json("consolidate", "-m", str(walk), "--budget", "3", "--max-distance", "inf")
    assert out["after"] == 3 and out["budget_met"] is True and out["max_distance"] is None
    assert sum(h.get("count", 1) for h in hits(walk)) == 30


def test_revisits_of_a_place_stay_apart(tmp_path: Path) -> None:
    """red, green, red at one place: the two red visits are never merged with each other."""
    mem = make_runs(tmp_path / "visits.mem", runs=["red", "green", "red"], spacing=0.1)
    out = rm_json("consolidate", "-m", str(mem), "--budget", "2")
    assert out["after"] == 2
    spans = [(h.get("first_t", h["t"]), h.get("last_t", h["t"])) for h in hits(mem)]
    # two runs of consecutive memories: a red+red group would span the green run and overlap
    assert spans[0][0] == T0 and spans[1][1] == T0 + 140 and spans[0][1] < spans[1][0]


def test_max_gap_keeps_runs_apart_in_time(tmp_path: Path) -> None:
    mem = make_runs(tmp_path / "same.mem", runs=["red", "red"], spacing=0.0)
    assert rm_json("consolidate", "-m", str(mem), "--max-similarity", "0.9", "--dry-run")["after"] == 1
    out = rm_json("consolidate", "-m", str(mem), "--max-similarity", "0.9", "--max-gap", "5")
    assert out["after"] == 10 and out["merged"] == 0 and len(records(mem)) == 10


def test_forgetting_a_representative_drops_its_group(walk: Path) -> None:
    rm_json("consolidate", "-m", str(walk), "--max-similarity", "0.95")
    rep = hits(walk)[1]
    out = rm_json("forget", "-m", str(walk), "--ids", str(rep["id"]))
    assert out["removed"] == 1
    info = rm_json("info", "-m", str(walk))
    assert (info["memories"], info["consolidated"], info["memories_represented"]) == (5, 5, 25)
    assert_consistent(walk)


def test_the_latest_mode_counts_what_a_representative_stands_for(tmp_path: Path) -> None:
    """`search --latest` on a consolidated memory: the place's sightings, first and last time
    include the merged memories, and its hits carry count and span like every other hit."""
    from ravenmem.types import Frame, Pose
    from tests.conftest import solid

    day, east, west, north = 86_400.0, 0.0, math.pi, math.pi / 2

    def look(t: float, colour: str, x: float, yaw: float) -> Frame:
        return Frame(image=solid(colour), t=T0 + t, pose=Pose(x, 0.0, 0.5, yaw), source="s", index=int(t))

    frames = [look(t, "red", 0.0, east) for t in (0, 1, 2)] + [look(t, "black", 0.0, west) for t in (3, 4)]
    frames += [look(5 + i, "black", 3.0 + 2 * i, north) for i in range(10)]
    frames += [look(day + t, "black", 0.0, east) for t in (0, 1)] + [look(day + 2, "black", 6.0, west)]
    frames += [look(day + t, "red", 10.0, north) for t in (3, 4, 5)]
    path = tmp_path / "moved.mem"
    with ravenmem.create(path, embedder=ColorEmbedder(), ocr=False, thumb_size=16) as m:
        m.add_frames(frames)
    rm_json("consolidate", "-m", str(path), "--max-similarity", "0.99")
    now = [h for h in hits(path) if h["t"] >= T0 + day + 3]
    assert len(now) == 1 and now[0]["count"] == 3  # the second red visit is one representative
    rows = rm_json("search", "--like", str(now[0]["id"]), "--latest", "-k", "5", "-m", str(path))["results"]
    sightings = [r for r in rows if r["change"]["role"] == "sighting"]
    assert [r["change"]["verdict"] for r in sightings] == ["not revisited", "moved"]
    for r, (first, last) in zip(sightings, [(day + 3, day + 5), (0, 2)]):
        assert (r["count"], r["first_t"], r["last_t"]) == (3, T0 + first, T0 + last)
        c = r["change"]
        assert (c["sightings"], c["first_seen"], c["last_seen"]) == (3, T0 + first, T0 + last)
        assert f"seen 3 times from {fmt_time(T0 + first)} to {fmt_time(T0 + last)}" in c["text"]
    revisit = next(r for r in rows if r["change"]["role"] == "revisit")
    assert revisit["count"] == 2 and revisit["first_t"] == T0 + day  # the empty place, seen twice
    with ravenmem.open(path) as m:  # what the offline reasoner and the agent read
        w = m.last_seen(memory_id=now[0]["id"])
    assert w.now is not None and w.now.last_t == T0 + day + 5 and w.now.seen == 3


def test_the_agent_reads_what_a_representative_stands_for(walk: Path) -> None:
    from ravenmem.agent.tool_calls import ToolRunner, WorkingMemory

    rm_json("consolidate", "-m", str(walk), "--max-similarity", "0.95")
    with ravenmem.open(walk) as m:
        out = ToolRunner(m, top_k=10, attach_images=False).run(
            "search_time", {"time": "start"}, WorkingMemory()
        )
    lines = out.text.splitlines()[1:]
    assert len(lines) == 6
    assert f"stands for {PER_RUN} memories seen from {fmt_time(T0)} to {fmt_time(T0 + 40)}" in lines[0]


def test_dry_run_and_bad_input_change_nothing(walk: Path) -> None:
    out = rm_json("consolidate", "-m", str(walk), "--budget", "10", "--dry-run")
    assert out["dry_run"] and out["after"] == 10 and out["merged"] == 20 and out["thumbnails"] == 20
    assert len(records(walk)) == 30 and len(thumbs_on_disk(walk)) == 30
    assert not (walk / "lifelong.sqlite").exists()
    for args, says in [
        ([], "give --budget"),
        (["--budget", "0"], "--budget"),
        (["--budget", "x"], "--budget"),
        (["--max-similarity", "2"], "--max-similarity"),
        (["--budget", "5", "--max-distance", "0"], "--max-distance"),
        (["--budget", "5", "--max-distance", "nan"], "--max-distance"),
        (["--budget", "5", "--max-gap", "-1"], "--max-gap"),
    ]:
        assert says in assert_one_line_error(rm("consolidate", "-m", str(walk), *args))
    assert len(records(walk)) == 30


def test_plan_merges_neighbours_by_similarity_and_picks_the_medoid() -> None:
    rng = np.random.default_rng(0)
    base = rng.normal(size=(3, 8))
    emb = np.repeat(base, 4, axis=0) + rng.normal(0, 0.05, (12, 8))
    emb /= np.linalg.norm(emb, axis=1, keepdims=True)
    t = np.arange(12, dtype=float)
    xy = np.zeros((12, 2))
    src = np.zeros(12, np.int64)
    counts = np.ones(12, np.int64)
    spans = np.stack([t, t], 1)
    p = plan(t, xy, src, emb, counts, spans, budget=3)
    assert p.entries_after == 3 and len(p.reps) == 3
    for rep, drop, (n, first, last) in zip(p.reps, p.drops, p.groups):
        members = sorted([rep, *drop])
        assert members == list(range(members[0], members[0] + 4)) and n == 4
        mean = emb[members].sum(0)
        assert rep == members[int(np.argmax(emb[members] @ mean))]
        assert (first, last) == (members[0], members[-1])
    # shuffled input order, two sources: runs never cross sources, indices map back
    perm = rng.permutation(12)
    src2 = (np.arange(12) >= 6).astype(np.int64)
    q = plan(t[perm], xy[perm], src2[perm], emb[perm], counts, spans[perm], budget=2)
    groups = [sorted(perm[[r, *d]].tolist()) for r, d in zip(q.reps, q.drops)]
    assert sorted(groups) == [list(range(6)), list(range(6, 12))]
    # counts weigh in: an entry standing for 10 memories adds 10 to its run's count
    c2 = counts.copy()
    c2[0] = 10
    r = plan(t, xy, src, emb, c2, spans, budget=3)
    assert sorted(g[0] for g in r.groups) == [4, 4, 13]
    # similarity threshold alone: only pairs above it merge
    s = plan(t, xy, src, emb, counts, spans, max_similarity=0.9)
    assert s.entries_after == 3 and s.lowest is not None and s.lowest > 0.9
