"""Scoring one answer and summarising a run, as the papers report them.

Rows are plain dicts (one JSONL line each) that carry the question, the ground truth, the
method's full answer and what was predicted; `score_row` needs nothing else, so a run folder
can be re-scored with other thresholds without the dataset or the memory.

- position: right when the predicted [x, y, z] is within the threshold of any accepted position
  (NaVQA 15 m; per question / per split otherwise); error = distance to the nearest one.
- time: within `time_s` (default 30 s = 0.5 min) of an accepted instant or inside the window.
- duration: within `duration_s` (default 30 s) of the true duration.
- frame: goal j right when the j-th predicted frame time is within the frame tolerance of an
  accepted frame of goal j (FindingDory multi-goal answers in order; `[[-1]]` = nothing seen);
  `relaxed` is FindingDory's per-goal precision product.
- binary: predicted yes/no equals the truth. text: an LLM judge's verdict, or not scored.

Besides its type's criterion, every question whose truth names frames is also scored by frame
(`frame_correct`) and every one with positions by position (`pos_correct`): RAVEN-QA's headline
is frame accuracy with position accuracy beside it, swept over thresholds by `position_sweep`.

Scoring rules (`Thresholds.scoring`): "paper" is the above. "release" applies the RAVEN-QA
release scorer's own rule to RAVEN-QA rows: an answer's time is right when it is within 2 s
(whole seconds) of the time the release gives an accepted frame (questions whose answer frames
have no timestamp are left out, as that scorer leaves them out), and a position is right when its
x, y distance to an accepted position is under the threshold. FindingDory's official scorer and
NaVQA's are the paper rule already (frame rounded to the nearest, in its goal's set; errors).

Every accuracy comes with a 95 % bootstrap interval over questions (`BOOTSTRAP` resamples with a
fixed seed, so the same rows always give the same interval) and the number of questions scored.
"""

from __future__ import annotations

import math
import re
from collections import defaultdict
from collections.abc import Iterable
from typing import Any

import numpy as np

from ..agent.schema import Answer
from .answer_forms import read_goals
from .config import RAVEN_QA, Thresholds
from .types import Episode, Question

DEFAULT_POS_M = 1.0  # when neither the question, the dataset nor the user gives a threshold
SWEEP_M = (0.25, 0.5, 1.0, 2.0, 3.0, 5.0, 10.0, 15.0, 25.0)  # the position-threshold sweep (metres)
BREAKDOWNS = ("type", "category", "horizon", "subset", "split")
NOT_JUDGED = "text answer not judged (no LLM judge configured)"
BOOTSTRAP = 1000  # resamples of the questions behind each 95 % interval
BOOTSTRAP_SEED = 20
RELEASE_TIME_S = 2.0  # the RAVEN-QA release scorer: |predicted - true| < 2 s, in whole seconds
NO_STAMP = "the release gives no timestamp for this answer's frames (its scorer leaves the question out)"
# NaVQA's tables group question types: descriptive (binary + text), positional, temporal (time + duration)
KINDS = {
    "binary": "descriptive",
    "text": "descriptive",
    "position": "positional",
    "time": "temporal",
    "duration": "temporal",
}


def goal_times(q: Question, ep: Episode) -> list[list[float]]:
    """Accepted frames per goal as times (frame indices and file names mapped through the episode)."""
    t = q.truth
    if t.frames and ep.frame_times:
        return [[ep.frame_times[i] for i in g if 0 <= i < len(ep.frame_times)] for g in t.frames]
    if t.files and ep.frame_files:
        idx = {f: i for i, f in enumerate(ep.frame_files)}
        times = [ep.frame_times[idx[f]] for f in t.files if f in idx]
        if times:
            return [times]
    if q.type == "frame" and t.times:
        return [list(t.times)]
    return []


def truth_row(q: Question, ep: Episode) -> dict[str, Any]:
    d = q.truth.to_dict()
    gt = goal_times(q, ep)
    if gt:
        d["goal_times"] = gt
    return d


def parse_yes(text: str) -> bool | None:
    w = (text or "").strip().lower()
    if re.match(r"^(yes|yeah|yep|true)\b", w):
        return True
    if re.match(r"^(no|nope|false|never)\b", w):
        return False
    return None


def prediction(a: Answer, q: Question, ep: Episode, fields: dict[str, Any] | None = None) -> dict[str, Any]:
    """What the answer predicts, in the units ground truth uses (frames as times). `fields` are
    the answer fields of the model's own reply (`answer_forms.reply_fields`): a multi-goal
    answer may sit there in the form a release's prompt asks for."""
    yes = a.yes if a.yes is not None else parse_yes(a.text)
    seq: list[float] = [] if a.time is None else [float(a.time)]
    for e in a.evidence:
        if all(abs(e.t - s) > 1e-6 for s in seq):
            seq.append(float(e.t))
    k = max(1, len(q.truth.frames))
    read = read_goals(a.text, fields or {}, ep.frame_times) if q.type == "frame" else None
    if read is not None:  # every goal's time, in the form the answer gave them
        goals, none, form = read.goals, read.none, read.form
        firsts = [g[0] for g in goals if g]
        seq = firsts + [x for x in seq if all(abs(x - f) > 1e-6 for f in firsts)]
    else:
        goals, none, form = [[s] for s in seq[:k]], False, "answer time" if seq else "none"
    frames = [ep.nearest_frame(s) for s in seq[:k]] if ep.frame_times else []
    out: dict[str, Any] = {
        "position": a.position,
        "yaw": a.yaw,  # radians, as Answer.yaw (and ROS) has it
        "time": a.time,
        "duration": a.duration,
        "yes": yes,
        "found": a.found and not none,
        "goal_times": goals,
        "frames": frames,
    }
    if q.type == "frame":
        out["goal_form"] = form
    if ep.frame_files and frames:
        out["files"] = [ep.frame_files[i] for i in frames if i is not None]
    return out


def _dist(p: list[float], g: list[float], planar: bool) -> float:
    p3 = (list(p) + [0.0, 0.0, 0.0])[:3]
    g3 = (list(g) + [0.0, 0.0, 0.0])[:3]
    dz = 0.0 if planar else p3[2] - g3[2]
    return math.sqrt((p3[0] - g3[0]) ** 2 + (p3[1] - g3[1]) ** 2 + dz * dz)


def _frame_score(
    goals: list[list[float]], pred: list[list[float]], tol: float
) -> tuple[bool, float, float | None]:
    """(strict ordered correctness, FindingDory relaxed score, temporal error of goal 0)."""

    def hit(p: float, g: list[float]) -> bool:
        return any(abs(p - x) <= tol for x in g)

    strict = len(pred) >= len(goals) and all(pred[j] and hit(pred[j][0], goals[j]) for j in range(len(goals)))
    relaxed = 0.0
    if len(pred) == len(goals):
        precisions = [sum(hit(p, g) for p in ps) / len(ps) if ps else 0.0 for ps, g in zip(pred, goals)]
        relaxed = float(np.prod(precisions))
    err = min(abs(pred[0][0] - x) for x in goals[0]) if pred and pred[0] and goals and goals[0] else None
    return strict, relaxed, err


def _frame_tol(row: dict[str, Any], thr: Thresholds) -> float:
    if thr.frame_s is not None:
        return thr.frame_s
    return float(row["truth"].get("time_tol") or row.get("frame_tol") or 0.5)


def rule_of(row: dict[str, Any], thr: Thresholds) -> str:
    """The scoring rule this row is scored by: "release" only for RAVEN-QA rows (the other
    releases' scorers are the paper's rule already)."""
    kind = str(row.get("dataset", "")).partition(":")[0]
    return "release" if thr.scoring == "release" and kind in RAVEN_QA else "paper"


def _position_part(row: dict[str, Any], thr: Thresholds, rule: str) -> dict[str, Any]:
    """Position accuracy of an answer: within the threshold of an accepted position (the
    release rule: x, y distance strictly under it)."""
    t, p, failed = row["truth"], row["pred"], row["answer"].get("failed")
    subset = row["question"].get("subset") or ""
    tol = t.get("pos_tol") or thr.position_for(subset) or row.get("pos_threshold") or DEFAULT_POS_M
    out: dict[str, Any] = {"threshold_m": tol, "pos_correct": False}
    if p.get("position") is not None:
        planar = thr.planar or rule == "release"
        out["pos_error_m"] = min(_dist(p["position"], g, planar) for g in t["positions"])
        within = out["pos_error_m"] < tol if rule == "release" else out["pos_error_m"] <= tol
        out["pos_correct"] = within and not failed
    return out


def _release_time_part(row: dict[str, Any]) -> dict[str, Any]:
    """The RAVEN-QA release scorer's time rule: the answer's time within 2 s (whole seconds)
    of a time the release gives an accepted frame."""
    t, p = row["truth"], row["pred"]
    if not t.get("times"):
        return {"skipped": NO_STAMP}
    pt = p.get("time")
    if pt is None and p.get("goal_times") and p["goal_times"][0]:
        pt = p["goal_times"][0][0]
    if pt is None:
        return {"frame_correct": False}
    err = min(abs(math.floor(pt) - math.floor(x)) for x in t["times"])
    return {
        "frame_correct": err < RELEASE_TIME_S and not row["answer"].get("failed"),
        "frame_error_s": float(err),
    }


def _frame_part(row: dict[str, Any], thr: Thresholds) -> dict[str, Any]:
    """Frame accuracy (the answer names an accepted frame, goal by goal), relaxed score, time error."""
    strict, relaxed, err = _frame_score(
        row["truth"]["goal_times"], row["pred"].get("goal_times") or [], _frame_tol(row, thr)
    )
    out: dict[str, Any] = {"frame_correct": strict and not row["answer"].get("failed"), "relaxed": relaxed}
    if err is not None:
        out["frame_error_s"] = err
    return out


def score_row(row: dict[str, Any], thr: Thresholds) -> dict[str, Any]:
    """Score one answer row (see the module docstring). correct=None means 'not scored' with a reason.

    `correct` is the question type's own criterion (a RAVEN-QA question naming frames: the
    frame). Whatever the type, a question with accepted frames also gets `frame_correct` and one
    with accepted positions `pos_correct` (with `threshold_m` and `pos_error_m`), so a report
    can show frame and position accuracy side by side."""
    qtype = row["question"]["type"]
    t = row["truth"]
    p = row["pred"]
    failed = bool(row["answer"].get("failed"))
    rule = rule_of(row, thr)
    s: dict[str, Any] = {"correct": None, "rule": rule}
    meta = row["question"].get("meta", {})
    if meta.get("truth_error"):
        s["skipped"] = s["truth_error"] = meta["truth_error"]
        return s
    if meta.get("unscorable"):
        s["skipped"] = meta["unscorable"]
        return s
    if failed:
        s["correct"] = False
        s["failed"] = True
    if t.get("none"):
        s["correct"] = not p.get("found", True) and not failed
        return s
    if t.get("positions"):
        s.update(_position_part(row, thr, rule))
    if t.get("goal_times"):
        s.update(_release_time_part(row) if rule == "release" else _frame_part(row, thr))
    if qtype == "position":
        s["correct"] = bool(s.get("pos_correct"))
    elif qtype == "frame":
        if rule == "release" and "frame_correct" not in s:
            s["skipped"] = s.get("skipped") or NO_STAMP
            s["correct"] = None
            return s
        if not t.get("goal_times"):
            s["skipped"] = "no accepted frame could be placed in time"
            s["correct"] = None
            return s
        s["correct"] = s["frame_correct"]
        if "frame_error_s" in s:
            s["time_error_s"] = s["frame_error_s"]
    elif qtype == "time":
        tol = t.get("time_tol") or thr.time_s
        pt = p.get("time")
        if pt is None and p.get("goal_times"):
            pt = p["goal_times"][0][0]
        if pt is not None and (t.get("times") or t.get("window")):
            errs = [abs(pt - x) for x in t.get("times", [])]
            if t.get("window"):
                lo, hi = t["window"]
                errs.append(max(lo - pt, 0.0, pt - hi))
            s["time_error_s"] = min(errs)
            s["correct"] = s["time_error_s"] <= tol and not failed
        else:
            s["correct"] = False
    elif qtype == "duration":
        tol = t.get("time_tol") or thr.duration_s
        if p.get("duration") is not None and t.get("duration") is not None:
            s["duration_error_s"] = abs(float(p["duration"]) - float(t["duration"]))
            s["correct"] = s["duration_error_s"] <= tol and not failed
        else:
            s["correct"] = False
    elif qtype == "binary":
        s["correct"] = p.get("yes") is not None and p["yes"] == t.get("yes") and not failed
    elif qtype == "text":
        verdict = row.get("judge")
        if failed:
            s["correct"] = False
        elif verdict and verdict.get("correct") is not None:
            s["correct"] = bool(verdict["correct"])
        else:
            s["skipped"] = NOT_JUDGED
    return s


# ------------------------------------------------------------------------------------ summaries
def mean_std(vals: Iterable[float | None]) -> dict[str, Any]:
    v = np.asarray([x for x in vals if x is not None and np.isfinite(x)], dtype=float)
    if v.size == 0:
        return {"mean": None, "std": None, "n": 0}
    return {"mean": float(v.mean()), "std": float(v.std(ddof=1)) if v.size > 1 else 0.0, "n": int(v.size)}


def _with_median(vals: list[float]) -> dict[str, Any]:
    out = mean_std(vals)
    out["median"] = float(np.median(vals)) if vals else None
    return out


def bootstrap_ci(table: np.ndarray, resamples: int = BOOTSTRAP) -> tuple[float, float] | None:
    """95 % interval of the accuracy over questions x seeds (NaN = not scored), by resampling the
    questions with replacement: each resample's accuracy is the mean over seeds of the per-seed
    means, as the point estimate is. A fixed seed makes it a function of the rows alone."""
    if table.size == 0 or not np.isfinite(table).any():
        return None
    rng = np.random.default_rng(BOOTSTRAP_SEED)
    idx = rng.integers(0, table.shape[0], size=(resamples, table.shape[0]))
    scored_all = np.isfinite(table)
    values = np.where(scored_all, table, 0.0)
    parts = []
    for chunk in np.array_split(idx, max(1, resamples // 100)):  # bounded memory on large datasets
        sums = values[chunk].sum(axis=1)  # resamples x seeds
        counts = scored_all[chunk].sum(axis=1)
        parts.append(np.where(counts > 0, sums / np.maximum(counts, 1), np.nan))
    per_seed = np.concatenate(parts)
    usable = np.isfinite(per_seed).any(axis=1)
    if not usable.any():
        return None
    accs = np.nanmean(per_seed[usable], axis=1)
    lo, hi = np.percentile(accs, [2.5, 97.5])
    return float(lo), float(hi)


def seed_accuracy(rows: list[dict[str, Any]], key: str = "correct") -> dict[str, Any]:
    """Accuracy per seed, then mean +- std over seeds (n = scored rows over all seeds), with the
    questions scored and a 95 % bootstrap interval over questions (`ci`)."""
    per_seed: dict[int, list[float]] = defaultdict(list)
    cells: dict[tuple[str, int], float] = {}
    for r in rows:
        c = r["score"].get(key)
        if c is not None:
            per_seed[int(r["seed"])].append(float(c))
            cells[(str(r["qid"]), int(r["seed"]))] = float(c)
    accs = [float(np.mean(v)) for v in per_seed.values() if v]
    out = mean_std(accs)
    out["n"] = sum(len(v) for v in per_seed.values())
    out["seeds"] = len(accs)
    qids = sorted({q for q, _ in cells})
    seeds = sorted(per_seed)
    out["questions"] = len(qids)
    table = np.full((len(qids), len(seeds)), np.nan)
    qi, si = {q: i for i, q in enumerate(qids)}, {s: j for j, s in enumerate(seeds)}
    for (q, sd), v in cells.items():
        table[qi[q], si[sd]] = v
    ci = bootstrap_ci(table)
    out["ci"] = list(ci) if ci is not None else None
    return out


def stats(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """Accuracy (the type's criterion), frame and position accuracy where the truth allows them,
    FindingDory's relaxed score on frame questions, and error statistics, over some rows."""
    out: dict[str, Any] = {"accuracy": seed_accuracy(rows), "rows": len(rows)}
    for key, name in (("frame_correct", "frame_accuracy"), ("pos_correct", "position_accuracy")):
        if any(key in r["score"] for r in rows):
            out[name] = seed_accuracy(rows, key)
    frames = [r for r in rows if r["question"]["type"] == "frame" and "relaxed" in r["score"]]
    if frames:
        out["relaxed"] = seed_accuracy(frames, "relaxed")
    out["pos_error_m"] = _with_median(
        [r["score"]["pos_error_m"] for r in rows if "pos_error_m" in r["score"]]
    )
    out["time_error_min"] = _with_median(
        [r["score"]["time_error_s"] / 60 for r in rows if "time_error_s" in r["score"]]
    )
    out["duration_error_min"] = mean_std(
        r["score"]["duration_error_s"] / 60 for r in rows if "duration_error_s" in r["score"]
    )
    # NaVQA's temporal error: time and duration errors together (minutes)
    out["temporal_error_min"] = mean_std(
        r["score"][k] / 60 for r in rows for k in ("time_error_s", "duration_error_s") if k in r["score"]
    )
    return out


def position_sweep(rows: list[dict[str, Any]], thresholds: Iterable[float] = SWEEP_M) -> dict[str, Any]:
    """Position accuracy at each threshold (metres), mean +- std over seeds: the curve behind the
    single-threshold column. A question without a predicted position is wrong at every threshold."""
    pos = [r for r in rows if "pos_correct" in r["score"]]
    per_seed: dict[int, list[float]] = defaultdict(list)
    for r in pos:
        err = r["score"].get("pos_error_m")
        per_seed[int(r["seed"])].append(math.inf if err is None or r["score"].get("failed") else float(err))
    out: dict[str, Any] = {"thresholds_m": [], "accuracy": []}
    for thr in thresholds:
        out["thresholds_m"].append(float(thr))
        out["accuracy"].append(
            mean_std(float(np.mean([e <= thr for e in errs])) for errs in per_seed.values())
        )
    return out


def group_key(r: dict[str, Any]) -> tuple[str, str, str, str]:
    """(method, embedder, VLM, variant): the rows one table line / one curve stands for."""
    return (r["method"], r.get("embedder") or "-", r.get("vlm") or "-", r.get("variant") or "")


def _breakdowns(rs: list[dict[str, Any]]) -> dict[str, dict[str, Any]]:
    """stats per value of each question attribute, per subset/split pair and per horizon/type pair."""
    by: dict[str, dict[str, Any]] = {}

    def part(name: str, key: Any) -> None:
        buckets: dict[str, list[dict[str, Any]]] = defaultdict(list)
        for r in rs:
            k = key(r["question"])
            if k:
                buckets[k].append(r)
        if buckets:
            by[name] = {k: stats(v) for k, v in sorted(buckets.items())}

    for attr in BREAKDOWNS:
        part(attr, lambda q, a=attr: q.get(a) or "")
    part(
        "subset_split", lambda q: f"{q['subset']}/{q['split']}" if q.get("subset") and q.get("split") else ""
    )
    part("horizon_type", lambda q: f"{q['horizon']}/{q['type']}" if q.get("horizon") else "")
    part(
        "horizon_kind",
        lambda q: f"{q['horizon']}/{KINDS[q['type']]}" if q.get("horizon") and q["type"] in KINDS else "",
    )
    return by


def summarize(
    rows: list[dict[str, Any]], thr: Thresholds | None = None, rescore: bool = True
) -> dict[str, Any]:
    """Per (method, embedder, VLM, variant): `stats` overall and broken down by type, category,
    horizon, subset and split; the position-threshold sweep; retrieval cost per question."""
    thr = thr or Thresholds()
    thr.check_subsets({str(r["question"].get("subset") or "") for r in rows})
    if rescore:
        for r in rows:
            r["score"] = score_row(r, thr)
    groups: dict[tuple[str, str, str, str], list[dict[str, Any]]] = defaultdict(list)
    for r in rows:
        groups[group_key(r)].append(r)
    out = []
    for (method, emb, vlm, variant), rs in sorted(groups.items()):
        g: dict[str, Any] = {
            "method": method,
            "embedder": emb,
            "vlm": vlm,
            "variant": variant,
            "seeds": sorted({int(r["seed"]) for r in rs}),
            "questions": len({r["qid"] for r in rs}),
        }
        g |= stats(rs)
        g["by"] = _breakdowns(rs)
        g["is_accuracy"] = {  # frame / position accuracy is every question's own criterion
            "frame_accuracy": all(
                r["question"]["type"] == "frame" for r in rs if "frame_correct" in r["score"]
            ),
            "position_accuracy": all(
                r["question"]["type"] == "position" for r in rs if "pos_correct" in r["score"]
            ),
        }
        if "position_accuracy" in g:
            g["pos_sweep"] = position_sweep(rs)
            g["pos_thresholds_m"] = sorted(
                {float(r["score"]["threshold_m"]) for r in rs if "threshold_m" in r["score"]}
            )
        costs = [r["answer"].get("cost", {}) for r in rs]
        g["alpha"] = mean_std(c.get("alpha") for c in costs)
        g["memories_shown"] = mean_std(c.get("memories_shown") for c in costs)
        g["images_per_q"] = mean_std(c.get("images") for c in costs)
        g["tokens_per_q"] = mean_std(
            (c.get("prompt_tokens", 0) + c.get("completion_tokens", 0)) for c in costs
        )
        g["tool_calls_per_q"] = mean_std(c.get("tool_calls") for c in costs)
        g["seconds_per_q"] = mean_std(r.get("wall_s") for r in rs)
        g["not_judged"] = sum(1 for r in rs if r["score"].get("skipped") == NOT_JUDGED)
        g["truth_errors"] = sorted(
            {(str(r["qid"]), str(r["score"]["truth_error"])) for r in rs if r["score"].get("truth_error")}
        )
        reasons: dict[str, set[str]] = defaultdict(set)
        for r in rs:
            why = r["score"].get("skipped")
            if (
                r["score"].get("correct") is None
                and why not in (None, NOT_JUDGED)
                and not r["score"].get("truth_error")
            ):
                reasons[str(why)].add(str(r["qid"]))
        g["skipped"] = {why: len(q) for why, q in sorted(reasons.items())}
        g["unscorable"] = sum(g["skipped"].values())
        g["rules"] = sorted({str(r["score"].get("rule", "paper")) for r in rs})
        g["failed"] = sum(1 for r in rs if r["answer"].get("failed"))
        g["ran_other"] = sorted(
            {r["ran"]["method"] for r in rs if r.get("ran") and r["ran"]["method"] != method}
        )
        out.append(g)
    rules = sorted({(r.get("dataset", ""), r["time_rule"]) for r in rows if r.get("time_rule")})
    notes = sorted({(r.get("dataset", ""), n) for r in rows for n in r.get("dataset_notes") or []})
    return {
        "thresholds": thr.to_dict(),
        "groups": out,
        "rows": len(rows),
        "time_rules": [{"dataset": d, "rule": rule} for d, rule in rules],
        "dataset_notes": [{"dataset": d, "note": n} for d, n in notes],
    }
