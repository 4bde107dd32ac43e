"""Studies as commands: the same questions under one changed setting, as a table and a curve.

- compression: keyframe stride 1, 2, 5, ... (other keyframe rules kept), plotted against frames
  per stored memory (the paper's sparsification curve, up to 250x);
- coverage: each recording cut where the robot has passed through a fraction of the grid cells
  (default 1 m) its whole trajectory visits, so questions about places not yet explored become
  unanswerable; meant for simulated episodes (exported in RAVEN-QA layout), works on any
  dataset with poses;
- consolidation: each memory consolidated (`ravenmem consolidate`) to a budget of memories, and
  beside it thinned uniformly in time to the same budget (forgetting the rest), plus the full
  memory: accuracy against memories kept (`consolidation_study`);
- the agent ablations, one method option swept (`option_study`): `top-k` (memories per tool
  call), `scores` (similarity scores shown to the model or hidden), `time-mode` (the time tool
  looking forward from the asked time, centred on it, or nearest in time first: the paper's ordering
  study) and `tool-calls` (the tool-call budget).

Every point is an ordinary run folder (`<out>/stride-5/`, `<out>/top_k-10/`, ...) with its rows
labelled by a variant, and `<out>/study.json` lists the points with accuracy and retrieval cost;
`ravenmem eval report <out>` draws the curve. Embeddings are cached, so each extra point costs
ingest and answers, not embedding.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import asdict, fields, replace
from pathlib import Path
from typing import Any

from ..errors import InputError
from ..fsio import atomic_write_json, publish_dir
from ..ingest.keyframes import KeyframeConfig
from ..memory.folder import LOCK, STUDY_DONE
from .config import OutputConfig, RunConfig
from .datasets import load_dataset
from .datasets.frames import Subsampled
from .runner import Runner, read_json, read_rows
from .types import Episode

# study name -> the method option it sweeps
OPTION_STUDIES = {
    "top-k": "top_k",
    "scores": "show_scores",
    "time-mode": "time_mode",
    "tool-calls": "max_tool_calls",
}


def keyframe_spec(cfg: KeyframeConfig) -> str:
    """A KeyframeConfig back as `key=value,...` (what --keyframes takes)."""
    parts = [f"{f.name}={getattr(cfg, f.name)}" for f in fields(cfg) if getattr(cfg, f.name) is not None]
    return ",".join(p for p in parts if p != "stride=1") or "all"


def _memory_totals(run_dir: Path) -> tuple[int, int]:
    """(memories, frames) summed over the episodes of a run (one memory per episode)."""
    per_ep: dict[str, dict[str, Any]] = {}
    for r in read_rows(run_dir):
        per_ep[r["episode"]] = r.get("memory") or {}
    return (
        sum(int(m.get("memories") or 0) for m in per_ep.values()),
        sum(int(m.get("frames") or 0) for m in per_ep.values()),
    )


def _point(g: dict[str, Any], **extra: Any) -> dict[str, Any]:
    """One method's result at one study setting: accuracy (and frame/position accuracy) and cost."""
    p = {
        "method": g["method"],
        "embedder": g["embedder"],
        "vlm": g["vlm"],
        "questions": g["questions"],
        "accuracy": g["accuracy"],
        "alpha": g["alpha"],
        "images_per_q": g["images_per_q"],
        "tokens_per_q": g["tokens_per_q"],
        "tool_calls_per_q": g["tool_calls_per_q"],
    }
    for key in ("frame_accuracy", "position_accuracy"):
        if key in g:
            p[key] = g[key]
    return extra | p


def _at(base: RunConfig, out: Path, variant: str, **changes: Any) -> RunConfig:
    return replace(base, output=OutputConfig(out=str(out)), variant=variant, **changes)


def _write(out: Path, doc: dict[str, Any]) -> None:
    out.mkdir(parents=True, exist_ok=True)
    atomic_write_json(out / "study.json", doc, indent=2, default=str)


def compression_study(
    base: RunConfig, strides: list[int], out: str | Path, **runner_kw: Any
) -> dict[str, Any]:
    """Run `base` once per keyframe stride; returns (and writes) the study's points."""
    if not strides or any(s < 1 for s in strides):
        raise InputError(f"--strides: give whole numbers >= 1, got {strides}")
    out = Path(out)
    kf = base.memory.keyframe_config()
    points = []
    for s in sorted(set(strides)):
        memory = replace(base.memory, keyframes=keyframe_spec(replace(kf, stride=s)))
        cfg = _at(base, out / f"stride-{s}", f"stride={s}", memory=memory)
        summary = Runner(cfg, **runner_kw).run()
        memories, frames = _memory_totals(out / f"stride-{s}")
        sparsification = frames / memories if memories else math.nan
        for g in summary["groups"]:
            points.append(
                _point(g, stride=s, memories=memories, frames=frames, sparsification=sparsification)
            )
    doc = {"study": "compression", "dataset": base.dataset.spec, "keyframes": asdict(kf), "points": points}
    _write(out, doc)
    return doc


def coverage_cut(ep: Episode, fraction: float, cell: float) -> int:
    """How many frames (from the start) it takes to visit `fraction` of the trajectory's cells."""
    if not ep.trajectory or not ep.has_poses:
        raise InputError(f"episode {ep.id}: the coverage study needs frame poses, and this episode has none")
    cells = [(math.floor(x / cell), math.floor(y / cell)) for _, x, y in ep.trajectory]
    total = len(set(cells))
    seen: set[tuple[int, int]] = set()
    for i, c in enumerate(cells):
        seen.add(c)
        if len(seen) >= fraction * total - 1e-9:
            return i + 1
    return len(cells)


def _cutter(cuts: dict[str, int]) -> Callable[[Episode], Subsampled]:
    return lambda e: Subsampled(e.frames(), 1, cuts[e.id])


def coverage_study(
    base: RunConfig,
    fractions: list[float],
    out: str | Path,
    cell: float = 1.0,
    episodes: list[Episode] | None = None,
    **runner_kw: Any,
) -> dict[str, Any]:
    """Run `base` on recordings cut at each coverage fraction; returns (and writes) the points."""
    if not fractions or any(not 0 < f <= 1 for f in fractions):
        raise InputError(f"--fractions: give numbers in (0, 1], got {fractions}")
    if cell <= 0:
        raise InputError(f"--cell must be > 0 metres, got {cell}")
    out = Path(out)
    ds = base.dataset
    eps = episodes if episodes is not None else load_dataset(ds.spec, queries=ds.queries, **ds.options())
    points = []
    for f in sorted(set(fractions)):
        cuts = {e.id: coverage_cut(e, f, cell) for e in eps}
        pct = round(100 * f)
        cfg = _at(base, out / f"coverage-{pct}", f"coverage={pct}%")
        summary = Runner(cfg, episodes=eps, **runner_kw).run(
            source_for=_cutter(cuts), extra_key={"coverage": f, "cell": cell}
        )
        memories, frames = _memory_totals(out / f"coverage-{pct}")
        for g in summary["groups"]:
            points.append(_point(g, coverage=f, memories=memories, frames=frames))
    doc = {"study": "coverage", "dataset": ds.spec, "cell_m": cell, "points": points}
    _write(out, doc)
    return doc


def _slug(value: Any) -> str:
    if isinstance(value, bool):
        return "on" if value else "off"
    return str(value).replace("/", "-")


def option_study(
    base: RunConfig, study: str, values: list[Any], out: str | Path, **runner_kw: Any
) -> dict[str, Any]:
    """Run `base` once per value of the method option a study sweeps (see OPTION_STUDIES); every
    method gets the value, and methods that do not use the option stay flat across the study."""
    if study not in OPTION_STUDIES:
        raise InputError(f"unknown study {study!r}; choose from {', '.join(OPTION_STUDIES)}")
    if not values:
        raise InputError(f"study {study}: give at least one value")
    option = OPTION_STUDIES[study]
    out = Path(out)
    points = []
    for value in dict.fromkeys(values):
        methods = replace(base.methods, **{option: value})
        cfg = _at(base, out / f"{option}-{_slug(value)}", f"{option}={_slug(value)}", methods=methods)
        summary = Runner(cfg, **runner_kw).run()
        for g in summary["groups"]:
            points.append(_point(g, value=value))
    doc = {
        "study": study,
        "option": option,
        "dataset": base.dataset.spec,
        "values": list(values),
        "points": points,
    }
    _write(out, doc)
    return doc


STRATEGIES = ("consolidate", "uniform")


def _reduced_copy(base: Path, dest: Path, strategy: str, budget: int, max_distance: float) -> dict[str, Any]:
    """`base` (a cached memory) copied to `dest` and reduced to `budget` memories; the copy is
    made under a temporary name and renamed when done, so a killed study redoes it."""
    import shutil
    import uuid

    import numpy as np

    import ravenmem

    marker = dest / STUDY_DONE
    if marker.exists():
        return dict(read_json(marker))
    if dest.exists():
        shutil.rmtree(dest)
    tmp = dest.with_name(f".{dest.name}.{uuid.uuid4().hex[:8]}")
    shutil.copytree(base, tmp, ignore=shutil.ignore_patterns(LOCK, ".*.tmp"))
    info: dict[str, Any]
    with ravenmem.open(tmp, writable=True) as mem:
        n = mem.count()
        if strategy == "consolidate":
            rep = mem.consolidate(budget=budget, max_distance=max_distance)
            info = {"kept": rep.after, "budget_met": rep.budget_met}
        else:  # uniform: keep `budget` memories evenly spaced in time, forget the others
            recs = mem.all_records()
            keep = {recs[int(i)].id for i in np.unique(np.linspace(0, n - 1, min(budget, n)).round())}
            mem.forget(ids=[r.id for r in recs if r.id not in keep])
            info = {"kept": mem.count(), "budget_met": mem.count() <= budget}
    info |= {"strategy": strategy, "budget": budget, "memories_before": n}
    atomic_write_json(tmp / STUDY_DONE, info)
    publish_dir(tmp, dest)
    return info


def consolidation_study(
    base: RunConfig,
    budgets: list[int],
    out: str | Path,
    strategies: tuple[str, ...] = STRATEGIES,
    max_distance: float = 1.0,
    episodes: list[Episode] | None = None,
    **runner_kw: Any,
) -> dict[str, Any]:
    """Accuracy against the number of memories kept: each episode's memory (built once, as
    `base` builds it) consolidated to each budget, and thinned uniformly in time to the same
    budget; the full memory is the reference point. Returns (and writes) the points."""
    import hashlib

    from .cache import CachingEmbedder, build_memory

    if not budgets or any(b < 1 for b in budgets):
        raise InputError(f"--budgets: give whole numbers >= 1, got {budgets}")
    bad = [s for s in strategies if s not in STRATEGIES]
    if bad or not strategies:
        raise InputError(f"--strategies: choose from {', '.join(STRATEGIES)}, got {', '.join(bad) or 'none'}")
    out = Path(out)
    ds, mcfg = base.dataset, base.memory
    eps = episodes if episodes is not None else load_dataset(ds.spec, queries=ds.queries, **ds.options())
    inner = runner_kw.get("embedder")
    if inner is None:
        from ..embed.base import create_embedder

        inner = create_embedder(base.models.embedder)
    emb = CachingEmbedder(inner, Path(mcfg.cache_dir) / "embeddings")
    bases: dict[str, tuple[Path, Episode]] = {}
    try:
        for ep in eps:
            mem, info = build_memory(
                ep, Path(mcfg.cache_dir), emb, mcfg.keyframe_config(), mcfg.ocr, mcfg.thumb_size
            )
            path = mem.path
            t0 = ep.t0 if ep.t0 is not None else (info.get("first_t") or mem.time_span()[0])
            mem.close()
            bases[ep.id] = (path, replace(ep, t0=t0))
    finally:
        emb.close()
    points: list[dict[str, Any]] = []

    def run_point(label: str, strategy: str, budget: int | None, eps_at: list[Episode], kept: int) -> None:
        cfg = _at(base, out / label, label.replace("-", "=", 1))
        summary = Runner(cfg, episodes=eps_at, **runner_kw).run()
        for g in summary["groups"]:
            points.append(_point(g, strategy=strategy, budget=budget, value=kept, memories=kept))

    full = sum(_count(p) for p, _ in bases.values())
    run_point("full", "full", None, [e for _, e in bases.values()], full)
    for strategy in strategies:
        for budget in sorted(set(budgets), reverse=True):
            eps_at, kept = [], 0
            for path, ep in bases.values():
                tag = hashlib.sha1(str(path).encode()).hexdigest()[:12]
                dest = out / "memories" / f"{strategy}-{budget}" / tag
                info = _reduced_copy(path, dest, strategy, budget, max_distance)
                kept += int(info["kept"])
                eps_at.append(replace(ep, memory_path=dest))
            run_point(f"{strategy}-{budget}", strategy, budget, eps_at, kept)
    doc = {
        "study": "consolidation",
        "dataset": ds.spec,
        "keyframes": asdict(mcfg.keyframe_config()),
        "max_distance_m": max_distance,
        "points": points,
    }
    _write(out, doc)
    return doc


def _count(path: Path) -> int:
    import ravenmem

    with ravenmem.open(path) as mem:
        return mem.count()
