from __future__ import annotations

from typing import Any

import pytest

from ravenmem.agent.schema import Answer, Cost, Evidence
from ravenmem.eval.answer_forms import parse_frame_lists
from ravenmem.eval.metrics import Thresholds, parse_yes, score_row, summarize
from ravenmem.eval.runner import build_row
from ravenmem.eval.types import Episode, Question, Truth

T = 1000.0
EP = Episode(
    id="ep",
    dataset="t",
    key="k",
    frames=lambda: [],
    questions=[],
    frame_times=[T + i for i in range(10)],
    frame_files=[f"f{i}.jpg" for i in range(10)],
    pos_threshold=15.0,
    frame_tol=0.5,
)


def row(
    q: Question,
    ans: Answer,
    thr: Thresholds | None = None,
    seed: int = 0,
    method: str = "m",
    ep: Episode = EP,
    **kw: Any,
) -> dict[str, Any]:
    ran = {"method": method, "model": kw.pop("vlm", None), "embedder": kw.pop("embedder", "")}
    return build_row(ep, q, method, seed, ans, thr or Thresholds(), ran=ran, **kw)


def ev(t: float) -> Evidence:
    return Evidence(id=0, t=t, x=0.0, y=0.0)


def test_position_threshold_sources() -> None:
    q = Question("q", "Where is it?", "position", Truth(positions=[[0, 0, 0], [100, 0, 0]]))
    r = row(q, Answer(position=[10.0, 0.0, 0.0]))
    assert r["score"]["pos_error_m"] == 10.0 and r["score"]["correct"]  # NaVQA-style 15 m from the episode
    assert not score_row(r, Thresholds(position_m=5.0))["correct"]  # user threshold wins over the dataset's
    q.truth.pos_tol = 12.0
    assert score_row(row(q, Answer(position=[10.0, 0.0, 0.0])), Thresholds(position_m=5.0))["correct"]
    assert row(q, Answer(position=[97.0, 0.0, 4.0]))["score"]["pos_error_m"] == pytest.approx(5.0)
    assert row(q, Answer(position=[97.0, 0.0, 4.0]), Thresholds(planar=True))["score"]["pos_error_m"] == 3.0
    miss = row(q, Answer(position=None))
    assert miss["score"]["correct"] is False and "pos_error_m" not in miss["score"]
    failed = row(q, Answer(position=[0.0, 0.0, 0.0], failed=True, error="boom"))
    assert failed["score"]["correct"] is False and failed["score"]["failed"]


def test_position_question_also_scores_the_frame() -> None:
    q = Question("q", "Where?", "position", Truth(positions=[[4, 0, 0]], files=["f4.jpg"]))
    r = row(q, Answer(position=[4.0, 0.0, 0.0], evidence=[ev(T + 4)]))
    assert r["score"]["correct"] and r["score"]["frame_correct"] and r["pred"]["files"] == ["f4.jpg"]
    assert not row(q, Answer(position=[4.0, 0.0, 0.0], evidence=[ev(T + 6)]))["score"]["frame_correct"]


def test_time_window_and_duration() -> None:
    q = Question("q", "When?", "time", Truth(times=[T + 100]))
    assert row(q, Answer(time=T + 129))["score"]["correct"]  # 0.5 min default
    r = row(q, Answer(time=T + 131))
    assert not r["score"]["correct"] and r["score"]["time_error_s"] == pytest.approx(31)
    w = Question("w", "When?", "time", Truth(window=[T + 10, T + 20]))
    assert row(w, Answer(time=T + 15))["score"]["time_error_s"] == 0.0
    assert row(w, Answer(time=T + 60), Thresholds(time_s=10))["score"]["time_error_s"] == 40.0
    d = Question("d", "How long?", "duration", Truth(duration=120.0))
    assert row(d, Answer(duration=140.0))["score"]["correct"]
    assert not row(d, Answer(duration=200.0))["score"]["correct"]


def test_frames_in_order_relaxed_and_none() -> None:
    q = Question("q", "Red then blue", "frame", Truth(frames=[[0, 1], [8, 9]]))
    good = row(q, Answer(evidence=[ev(T + 1), ev(T + 8)]))
    assert good["truth"]["goal_times"] == [[T, T + 1], [T + 8, T + 9]]
    assert good["score"]["correct"] and good["score"]["relaxed"] == 1.0
    swapped = row(q, Answer(evidence=[ev(T + 8), ev(T + 1)]))
    assert not swapped["score"]["correct"] and swapped["score"]["relaxed"] == 0.0
    short = row(q, Answer(evidence=[ev(T + 1)]))
    assert not short["score"]["correct"]
    # a FindingDory-native reply in the text wins, relaxed = product of per-goal precision
    native = row(q, Answer(text="The frames are [[0, 5], [9]]", evidence=[ev(T + 3)]))
    assert native["score"]["relaxed"] == pytest.approx(0.5) and native["score"]["correct"]
    none = Question("n", "Purple sofa?", "frame", Truth(none=True))
    assert row(none, Answer(found=False))["score"]["correct"]
    assert not row(none, Answer(found=True, evidence=[ev(T)]))["score"]["correct"]
    assert row(none, Answer(text="[[-1]]"))["score"]["correct"]


def test_frame_by_file_tolerance() -> None:
    q = Question("q", "Where?", "frame", Truth(files=["f5.jpg"]))
    ep = Episode(
        id="e",
        dataset="t",
        key="k",
        frames=lambda: [],
        questions=[],
        frame_times=EP.frame_times,
        frame_files=EP.frame_files,
        frame_tol=1.5,
    )
    assert row(q, Answer(evidence=[ev(T + 6)]), ep=ep)["score"]["correct"]  # neighbour frame counts
    assert not row(q, Answer(evidence=[ev(T + 7)]), ep=ep)["score"]["correct"]
    assert not row(q, Answer(evidence=[ev(T + 6)]), Thresholds(frame_s=0.2), ep=ep)["score"]["correct"]


def test_binary_text_and_unscorable() -> None:
    b = Question("b", "Did you see it?", "binary", Truth(yes=True))
    assert row(b, Answer(yes=True))["score"]["correct"]
    assert row(b, Answer(text="Yes, near the door."))["score"]["correct"]
    assert not row(b, Answer(text="No."))["score"]["correct"]
    t = Question("t", "What colour?", "text", Truth(text=["red"]))
    r = row(t, Answer(text="red"))
    assert r["score"]["correct"] is None and "no LLM judge" in r["score"]["skipped"]
    assert row(t, Answer(text="red"), judge={"correct": True})["score"]["correct"] is True
    u = Question("u", "?", "position", Truth(), meta={"unscorable": "no parsable ground truth"})
    assert row(u, Answer(position=[0.0, 0.0, 0.0]))["score"]["correct"] is None


def test_parsers() -> None:
    assert parse_frame_lists("I think [[3, 4], [10]] fits") == [[3, 4], [10]]
    assert parse_frame_lists("frames 3 and 4") is None
    assert parse_yes("Yes.") is True and parse_yes("no, never") is False and parse_yes("maybe") is None


def test_summary_mean_std_over_seeds_and_breakdowns() -> None:
    qs = [
        Question(
            f"q{i}",
            "Where?",
            "position",
            Truth(positions=[[0, 0, 0]]),
            category="spatial" if i < 2 else "other",
            horizon="short" if i % 2 else "long",
        )
        for i in range(4)
    ]
    rows = []
    for seed, good in ((0, 4), (1, 2)):  # seed 0: all right, seed 1: two right
        for i, q in enumerate(qs):
            pos = [1.0, 0.0, 0.0] if i < good else [50.0, 0.0, 0.0]
            cost = Cost(alpha=0.1 * (seed + 1), images=4, prompt_tokens=100, completion_tokens=10)
            rows.append(
                row(q, Answer(position=pos, cost=cost), seed=seed, method="raven", embedder="e", vlm="v")
            )
    rows.append(row(qs[0], Answer(position=[0.0, 0.0, 0.0]), method="random", embedder="e"))
    s = summarize(rows)
    g = {x["method"]: x for x in s["groups"]}
    acc = g["raven"]["accuracy"]
    assert acc["mean"] == pytest.approx(0.75) and acc["std"] == pytest.approx(0.35355, abs=1e-4)
    assert acc["seeds"] == 2 and acc["n"] == 8
    by = g["raven"]["by"]
    assert by["category"]["spatial"]["accuracy"]["mean"] == 1.0
    assert by["category"]["other"]["accuracy"]["mean"] == pytest.approx(0.5)
    assert set(by["horizon"]) == {"short", "long"} and set(by["horizon_type"]) == {
        "short/position",
        "long/position",
    }
    assert by["category"]["other"]["position_accuracy"]["mean"] == pytest.approx(0.5)
    # the threshold sweep: errors 1 m (6 answers) and 50 m (2); 15 m is the episode's threshold
    sweep = dict(zip(g["raven"]["pos_sweep"]["thresholds_m"], g["raven"]["pos_sweep"]["accuracy"]))
    assert (
        sweep[0.5]["mean"] == 0.0
        and sweep[1.0]["mean"] == pytest.approx(0.75)
        and sweep[25.0]["mean"] == 0.75
    )
    assert g["raven"]["pos_thresholds_m"] == [15.0]
    assert g["raven"]["alpha"]["mean"] == pytest.approx(0.15)
    assert g["raven"]["tokens_per_q"]["mean"] == 110 and g["raven"]["images_per_q"]["mean"] == 4
    assert g["raven"]["pos_error_m"]["median"] == pytest.approx(1.0)
    assert g["random"]["vlm"] == "-" and g["random"]["accuracy"]["mean"] == 1.0
    strict = {x["method"]: x for x in summarize(rows, Thresholds(position_m=0.5))["groups"]}
    assert strict["raven"]["accuracy"]["mean"] == 0.0 and strict["random"]["accuracy"]["mean"] == 1.0


def test_frame_question_also_scores_the_position_and_splits() -> None:
    """RAVEN-QA: frame accuracy is the criterion, position accuracy is reported beside it."""
    q = Question(
        "q", "Where?", "frame", Truth(positions=[[4, 0, 0]], files=["f4.jpg"]), subset="sim", split="hard"
    )
    ep = Episode(
        id="e",
        dataset="raven-qa",
        key="k",
        frames=lambda: [],
        questions=[],
        frame_times=EP.frame_times,
        frame_files=EP.frame_files,
        frame_tol=0.5,
        pos_threshold=2.0,
    )
    right = row(q, Answer(position=[4.0, 0.0, 0.0], evidence=[ev(T + 4)]), ep=ep)
    assert right["score"]["correct"] and right["score"]["frame_correct"] and right["score"]["pos_correct"]
    near = row(q, Answer(position=[5.0, 0.0, 0.0], evidence=[ev(T + 5)]), ep=ep)  # the next frame, 1 m off
    assert (
        near["score"]["correct"] is False
        and near["score"]["pos_correct"]
        and near["score"]["pos_error_m"] == 1.0
    )
    nowhere = row(q, Answer(evidence=[ev(T + 4)]), ep=ep)
    assert nowhere["score"]["correct"] and nowhere["score"]["pos_correct"] is False
    assert right["question"]["subset"] == "sim" and right["question"]["split"] == "hard"
    (g,) = summarize([right, near, nowhere])["groups"]
    assert g["frame_accuracy"]["mean"] == pytest.approx(2 / 3) == g["accuracy"]["mean"]
    assert g["position_accuracy"]["mean"] == pytest.approx(2 / 3)
    assert set(g["by"]["subset_split"]) == {"sim/hard"} and set(g["by"]["split"]) == {"hard"}
    sweep = dict(zip(g["pos_sweep"]["thresholds_m"], g["pos_sweep"]["accuracy"]))
    assert sweep[0.5]["mean"] == pytest.approx(1 / 3)  # no position: wrong at every threshold
