"""Studies as commands: accuracy vs keyframe sparsification and vs exploration coverage.

Compression: the same questions over memories built with keyframe stride 1, 2, 5, ... (other
keyframe rules kept), plotting accuracy against frames per stored memory (the paper's
sparsification curve, up to 250x). Coverage: each episode's recording cut where the robot has
passed through a given fraction of the grid cells (default 1 m) its full trajectory visits, so
questions about places not yet explored become unanswerable; meant for simulated episodes
(exported in RAVEN-QA layout) but works on any dataset with poses.

Every point is an ordinary run folder (`<out>/stride-5/`, `<out>/coverage-50/`) with its rows
labelled by a variant, and `<out>/study.json` lists the points; `ravenmem eval report <out>`
draws the curve. Embeddings are cached, so each extra point costs ingest and answers, not
embedding.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import asdict, fields, replace
from pathlib import Path
from typing import Any

from ..errors import InputError
from ..fsio import atomic_write_json
from ..ingest.keyframes import KeyframeConfig, parse_keyframes
from .datasets import load_dataset
from .datasets.frames import Subsampled
from .runner import RunConfig, Runner, read_rows
from .types import Episode


def keyframe_spec(cfg: KeyframeConfig) -> str:
    """A KeyframeConfig back as `key=value,...` (what --keyframes takes)."""
    parts = [f"{f.name}={getattr(cfg, f.name)}" for f in fields(cfg) if getattr(cfg, f.name) is not None]
    return ",".join(p for p in parts if p != "stride=1") or "all"


def _memory_totals(run_dir: Path) -> tuple[int, int]:
    """(memories, frames) summed over the episodes of a run (one memory per episode)."""
    per_ep: dict[str, dict[str, Any]] = {}
    for r in read_rows(run_dir):
        per_ep[r["episode"]] = r.get("memory") or {}
    return (sum(int(m.get("memories") or 0) for m in per_ep.values()),
            sum(int(m.get("frames") or 0) for m in per_ep.values()))  # fmt: skip


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
    kf = parse_keyframes(base.keyframes)
    points = []
    for s in sorted(set(strides)):
        cfg = replace(base, out=str(out / f"stride-{s}"), keyframes=keyframe_spec(replace(kf, stride=s)),
                      variant=f"stride={s}")  # fmt: skip
        summary = Runner(cfg, **runner_kw).run()
        memories, frames = _memory_totals(Path(cfg.out or ""))
        for g in summary["groups"]:
            points.append({"stride": s, "memories": memories, "frames": frames,
                           "sparsification": frames / memories if memories else math.nan, "method": g["method"],
                           "embedder": g["embedder"], "vlm": g["vlm"], "accuracy": g["accuracy"]})  # fmt: skip
    doc = {"study": "compression", "dataset": base.dataset, "keyframes": asdict(kf), "points": points}
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


def coverage_study(base: RunConfig, fractions: list[float], out: str | Path, cell: float = 1.0,
                   episodes: list[Episode] | None = None, **runner_kw: Any) -> dict[str, Any]:  # fmt: skip
    """Run `base` on recordings cut at each coverage fraction; returns (and writes) the points."""
    if not fractions or any(not 0 < f <= 1 for f in fractions):
        raise InputError(f"--fractions: give numbers in (0, 1], got {fractions}")
    if cell <= 0:
        raise InputError(f"--cell must be > 0 metres, got {cell}")
    out = Path(out)
    eps = (
        episodes
        if episodes is not None
        else load_dataset(base.dataset, queries=base.queries, **base.dataset_opts)
    )
    points = []
    for f in sorted(set(fractions)):
        cuts = {e.id: coverage_cut(e, f, cell) for e in eps}
        pct = round(100 * f)
        cfg = replace(base, out=str(out / f"coverage-{pct}"), variant=f"coverage={pct}%")
        runner = Runner(cfg, episodes=eps, **runner_kw)
        summary = runner.run(source_for=_cutter(cuts),
                             extra_key={"coverage": f, "cell": cell})  # fmt: skip
        memories, frames = _memory_totals(Path(cfg.out or ""))
        for g in summary["groups"]:
            points.append({"coverage": f, "memories": memories, "frames": frames, "method": g["method"],
                           "embedder": g["embedder"], "vlm": g["vlm"], "accuracy": g["accuracy"]})  # fmt: skip
    doc = {"study": "coverage", "dataset": base.dataset, "cell_m": cell, "points": points}
    _write(out, doc)
    return doc
