"""`ravenmem eval --replay RUN`: a finished run's numbers again, from what it recorded, with no model.

A run folder holds every answer (`answers.jsonl`, each with the model's full answer), every
model request and reply behind them (`model_io.jsonl`) and the settings (`manifest.json`).
Replaying re-scores the recorded answers: with the run's own settings the summary (and the
report of the folder `--out` writes) is the run's, number for number. Scoring settings
(thresholds, `--scoring`) may change, and fewer methods, seeds or episodes may be chosen; a
setting that changes answers (dataset, embedder, model, keyframes, any method option...) would
need new model replies, so it is refused with a line naming it, as is an answer from a model
whose reply the run did not record.
"""

from __future__ import annotations

import json
import shutil
from collections.abc import Callable, Mapping
from dataclasses import fields
from fnmatch import fnmatch
from pathlib import Path
from typing import Any

from ..errors import InputError
from ..fsio import atomic_write, atomic_write_json
from .config import IDENTITY, SECTIONS, RunConfig, build_run_config
from .metrics import summarize
from .recording import MANIFEST, MODEL_IO, ModelLog
from .runner import AnswerLog, _json_default, _needs_vlm, read_json

# run options that have no meaning for re-scoring recorded answers
NOT_REPLAYED = ("limit", "workers", "retry_failed", "cache_dir", "judge", "judge_base_url")
_IDENT_FLAGS = {
    "dataset": "--dataset",
    "queries": "--queries",
    "embedder": "--embedder",
    "vlm": "--vlm",
    "vlm_base_url": "--vlm-base-url",
    "keyframes": "--keyframes",
    "ocr": "--ocr",
    "thumb_size": "--thumb-size",
}


def _flag(section: str, name: str) -> str:
    for f in fields(SECTIONS[section]):
        if f.name == name and "flag" in f.metadata:
            return str(f.metadata["flag"]).split()[0].split("/")[0]
    return name


def changed_settings(old: RunConfig, new: RunConfig) -> list[str]:
    """The answer-changing settings that differ, as 'flag (old -> new)'."""
    a, b = old.identity(), new.identity()
    out = []
    for key in IDENTITY:
        if key in ("method_opts", "dataset_opts"):
            section = "methods" if key == "method_opts" else "dataset"
            for opt in sorted(set(a[key]) | set(b[key])):
                if a[key].get(opt) != b[key].get(opt):
                    out.append(f"{_flag(section, opt)} ({a[key].get(opt)} -> {b[key].get(opt)})")
        elif a[key] != b[key]:
            out.append(f"{_IDENT_FLAGS[key]} ({a[key]} -> {b[key]})")
    return out


def replay_run(
    run_dir: str | Path,
    values: Mapping[str, Any] | None = None,
    out: str | Path | None = None,
    build: Callable[..., RunConfig] = build_run_config,
    log: Callable[[str], None] | None = None,
) -> dict[str, Any]:
    """Re-score a run from its recorded answers (see the module docstring); `values` are the
    command-line options given (None = not given), `build(values, base)` makes the config."""
    root = Path(run_dir)
    where = f"--replay {root}"
    if not (root / MANIFEST).exists() or not (root / "answers.jsonl").exists():
        raise InputError(
            f"{where}: no manifest.json and answers.jsonl there (not a run folder this version recorded)"
        )
    man = read_json(root / MANIFEST)
    base = RunConfig.from_dict(man.get("settings") or {})
    given = dict(values or {})
    cfg = build(given, base)
    diffs = changed_settings(base, cfg)
    if diffs:
        raise InputError(
            f"{where}: {', '.join(diffs)} changed; those answers need new model replies (run without --replay)"
        )
    stray = [k for k in NOT_REPLAYED if given.get(k) is not None]
    if stray:
        flags = ", ".join("--" + k.replace("_", "-") for k in stray)
        raise InputError(f"{where}: {flags} do(es) not apply to a replay (it re-scores the recorded answers)")
    rows = AnswerLog(root / "answers.jsonl").rows()
    recorded = {r["method"] for r in rows}
    missing = [m for m in cfg.methods.names if m not in recorded]
    if missing:
        raise InputError(
            f"{where}: --method {', '.join(missing)}: the run holds no answers of it (it has {', '.join(sorted(recorded))})"
        )
    seeds = {int(r["seed"]) for r in rows}
    if not set(range(cfg.seeds)) <= seeds:
        raise InputError(
            f"{where}: --seeds {cfg.seeds}: the run holds seeds {', '.join(map(str, sorted(seeds)))}"
        )
    keep = [
        r
        for r in rows
        if r["method"] in cfg.methods.names
        and int(r["seed"]) < cfg.seeds
        and (not cfg.dataset.episodes or fnmatch(r["episode"], cfg.dataset.episodes))
    ]
    if not keep:
        raise InputError(f"{where}: no recorded answer matches --episodes {cfg.dataset.episodes!r}")
    replied = ModelLog(root / MODEL_IO).contexts()
    unrecorded = [
        r["key"]
        for r in keep
        if _needs_vlm(r["method"]) and not r["answer"].get("failed") and r["key"] not in replied
    ]
    if unrecorded:
        raise InputError(
            f"{where}: {len(unrecorded)} answer(s) from a model have no recorded reply in {MODEL_IO} "
            f"(first: {unrecorded[0]}); replay needs a run that recorded them"
        )
    summary = summarize(keep, cfg.thresholds)
    summary["replayed_from"] = str(root)
    summary["run_dir"] = str(out) if out is not None else ""
    if out is not None:
        _write(Path(out), root, keep, cfg, man, summary)
    if log is not None:
        log(f"eval: replayed {len(keep)} recorded answer(s) from {root} (no model asked)")
    return summary


def _write(
    out: Path,
    root: Path,
    rows: list[dict[str, Any]],
    cfg: RunConfig,
    man: dict[str, Any],
    summary: dict[str, Any],
) -> None:
    """A run folder of its own for the replayed numbers (never the recorded run's)."""
    if out.resolve() == root.resolve():
        raise InputError(f"--out {out}: a replay never writes into the run it replays; give another folder")
    if (out / "answers.jsonl").exists():
        raise InputError(f"--out {out} already holds a run; give an empty folder")
    out.mkdir(parents=True, exist_ok=True)
    text = "".join(json.dumps(r, default=_json_default) + "\n" for r in rows)
    atomic_write(out / "answers.jsonl", text.encode("utf-8"))
    atomic_write_json(out / "config.json", cfg.to_json(), indent=2, default=str)
    doc = man | {
        "replayed_from": str(root.resolve()),
        "scoring": {"rule": cfg.thresholds.scoring, "thresholds": cfg.thresholds.to_dict()},
    }
    atomic_write_json(out / MANIFEST, doc, indent=2, default=str)
    if (root / MODEL_IO).exists():
        shutil.copyfile(root / MODEL_IO, out / MODEL_IO)
    atomic_write_json(out / "summary.json", summary, indent=2, default=_json_default)
