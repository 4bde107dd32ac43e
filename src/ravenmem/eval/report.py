"""Reports: markdown tables laid out like the papers' (method x embedder x VLM, per category and
horizon) and PNG plots (accuracy per category, error CDFs, accuracy vs alpha, and the studies'
accuracy vs keyframe sparsification / coverage), from one run folder or a folder of runs.

Rows are re-scored with the thresholds given (default: the run's own), so a report can apply a
stricter criterion to answers already collected.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import InputError
from .metrics import Thresholds, summarize
from .runner import read_rows

TYPE_COLS = ("position", "time", "duration", "frame", "binary", "text")


def _pct(d: dict[str, Any] | None) -> str:
    if not d or d.get("mean") is None:
        return "n/a"
    s = f"{100 * d['mean']:.1f}"
    return s + (f" ± {100 * d['std']:.1f}" if d.get("seeds", 1) > 1 else "")


def _num(d: dict[str, Any] | None, digits: int = 2) -> str:
    if not d or d.get("mean") is None:
        return "n/a"
    return f"{d['mean']:.{digits}f} ± {d['std']:.{digits}f}"


def _method(g: dict[str, Any]) -> str:
    return g["method"] + (f" [{g['variant']}]" if g.get("variant") else "")


def _label(g: dict[str, Any]) -> str:
    parts = [_method(g), g["embedder"].rsplit("/", 1)[-1]] + ([g["vlm"]] if g["vlm"] != "-" else [])
    return " | ".join(parts)


def _used_thresholds(rows: list[dict[str, Any]]) -> str:
    vals = sorted({float(r["score"]["threshold_m"]) for r in rows if "threshold_m" in r["score"]})
    return ", ".join(f"{v:g} m" for v in vals) if vals else "n/a"


def _table(header: list[str], rows: list[list[str]]) -> str:
    out = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    out += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(out)


def _thresholds_of(run_dir: Path) -> Thresholds:
    cfg = run_dir / "config.json"
    if cfg.exists():
        return Thresholds.from_dict(json.loads(cfg.read_text(encoding="utf-8")).get("thresholds"))
    return Thresholds()


def markdown(summary: dict[str, Any], rows: list[dict[str, Any]], figs: dict[str, str],
             studies: list[dict[str, Any]]) -> str:  # fmt: skip
    groups = summary["groups"]
    datasets = sorted({r.get("dataset", "") for r in rows})
    thr = summary["thresholds"]
    lines = ["# Evaluation report", "",
             f"{len(rows)} answers, {len({r['qid'] for r in rows})} questions, dataset(s): "
             + ", ".join(f"`{d}`" for d in datasets), "",
             "Accuracy in % (mean ± std over seeds where there are several); errors mean ± std over answered "
             f"questions. Position threshold(s): {_used_thresholds(rows)}; time {thr['time_s'] / 60:g} min, "
             f"duration {thr['duration_s'] / 60:g} min.", "",
             "## Overall", ""]  # fmt: skip
    types = [t for t in TYPE_COLS if any(t in g["by_type"] for g in groups)]
    head = ["Method", "Embedder", "VLM", "Q", "Seeds", "Accuracy", *[t.capitalize() for t in types],
            "Pos. err (m)", "Time err (min)", "α", "Images/q", "Tokens/q", "s/q"]  # fmt: skip
    body = []
    for g in groups:
        body.append([_method(g), g["embedder"], g["vlm"], str(g["questions"]), str(len(g["seeds"])),
                     _pct(g["accuracy"]), *[_pct(g["by_type"].get(t)) for t in types], _num(g["pos_error_m"]),
                     _num(g["time_error_min"]), _num(g["alpha"], 3), _num(g["images_per_q"], 1),
                     _num(g["tokens_per_q"], 0), _num(g["seconds_per_q"], 2)])  # fmt: skip
    lines += [_table(head, body), ""]
    for field, title in (("by_category", "Accuracy per category"), ("by_horizon", "Accuracy per horizon")):
        keys = sorted({k for g in groups for k in g[field]})
        if field == "by_horizon":
            keys = [h for h in ("short", "medium", "long") if h in keys]
        if not keys:
            continue
        lines += [f"## {title}", "",
                  _table(["Method", "Embedder", "VLM", *keys],
                         [[_method(g), g["embedder"], g["vlm"], *[_pct(g[field].get(k)) for k in keys]] for g in groups]),
                  ""]  # fmt: skip
    extra = [g for g in groups if g.get("relaxed") or g.get("frame_accuracy")]
    if extra:
        lines += ["## Frame answers", "",
                  _table(["Method", "Embedder", "VLM", "Frame accuracy (position questions)", "Relaxed (frame questions, FindingDory style)"],
                         [[_method(g), g["embedder"], g["vlm"], _pct(g.get("frame_accuracy")), _pct(g.get("relaxed"))]
                          for g in extra]), ""]  # fmt: skip
    notes = []
    for g in groups:
        if g["not_judged"]:
            notes.append(f"- {_label(g)}: {g['not_judged']} text answer(s) not scored: no LLM judge was configured "
                         "(run with --judge MODEL).")  # fmt: skip
        if g["failed"]:
            notes.append(
                f"- {_label(g)}: {g['failed']} answer(s) failed (counted wrong; see `error` in answers.jsonl)."
            )
        if g["unscorable"] > 0:
            notes.append(
                f"- {_label(g)}: {g['unscorable']} question(s) without usable ground truth were not scored."
            )
    if notes:
        lines += ["## Notes", "", *notes, ""]
    for st in studies:
        lines += [f"## {st['study'].capitalize()} study (`{st.get('dataset', '')}`)", ""]
        if st["study"] == "compression":
            head = ["Stride", "Memories", "Frames", "Frames per memory", "Method", "Accuracy"]
            body = [[str(p["stride"]), str(p["memories"]), str(p["frames"]), f"{p['sparsification']:.1f}", p["method"],
                     _pct(p["accuracy"])] for p in st["points"]]  # fmt: skip
        else:
            head = ["Coverage", "Memories", "Method", "Accuracy"]
            body = [[f"{100 * p['coverage']:.0f}%", str(p["memories"]), p["method"], _pct(p["accuracy"])]
                    for p in st["points"]]  # fmt: skip
        lines += [_table(head, body), ""]
    if figs:
        lines += ["## Figures", ""] + [f"![{name}]({rel})" for name, rel in figs.items()] + [""]
    return "\n".join(lines)


# ------------------------------------------------------------------------------------ plots
def _plt() -> Any:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_categories(groups: list[dict[str, Any]], path: Path) -> bool:
    cats = sorted({k for g in groups for k in g["by_category"]})
    if not cats:
        return False
    plt = _plt()
    fig, ax = plt.subplots(figsize=(max(6.0, 1.3 * len(cats) + 2) + 2.5, 4.2))
    w = 0.8 / len(groups)
    x = np.arange(len(cats))
    for i, g in enumerate(groups):
        vals = [100 * (g["by_category"].get(c, {}).get("mean") or 0.0) for c in cats]
        errs = [100 * (g["by_category"].get(c, {}).get("std") or 0.0) for c in cats]
        ax.bar(x + (i - (len(groups) - 1) / 2) * w, vals, w, yerr=errs, capsize=3, label=_label(g))
    ax.set_xticks(x, cats, rotation=20, ha="right")
    ax.set_ylabel("accuracy (%)")
    ax.set_ylim(0, 105)
    ax.set_title("Accuracy per category")
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    ax.grid(axis="y", alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return True


def plot_error_cdfs(groups: list[dict[str, Any]], rows: list[dict[str, Any]], path: Path) -> bool:
    from .metrics import group_key

    kinds = [("pos_error_m", "position error (m)", 1.0), ("time_error_s", "time error (min)", 1 / 60)]
    have = [k for k in kinds if any(k[0] in r["score"] for r in rows)]
    if not have:
        return False
    plt = _plt()
    fig, axes = plt.subplots(1, len(have), figsize=(5.5 * len(have), 4.0), squeeze=False)
    for ax, (key, title, scale) in zip(axes[0], have):
        for g in groups:
            gk = (g["method"], g["embedder"], g["vlm"], g.get("variant") or "")
            errs = np.sort(
                [r["score"][key] * scale for r in rows if group_key(r) == gk and key in r["score"]]
            )
            if errs.size:
                ax.step(errs, np.arange(1, errs.size + 1) / errs.size, where="post", label=_label(g))
        ax.set_xlabel(title)
        ax.set_ylabel("fraction of questions")
        ax.set_ylim(0, 1.02)
        ax.grid(alpha=0.3)
        ax.set_title(f"CDF of {title}")
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return True


def plot_alpha(groups: list[dict[str, Any]], path: Path) -> bool:
    pts = [(g["alpha"]["mean"], g["accuracy"]["mean"], g) for g in groups
           if g["alpha"]["mean"] is not None and g["accuracy"]["mean"] is not None]  # fmt: skip
    if not pts:
        return False
    plt = _plt()
    fig, ax = plt.subplots(figsize=(8.5, 4.2))
    for a, acc, g in pts:
        ax.errorbar(
            [a], [100 * acc], yerr=[100 * (g["accuracy"]["std"] or 0.0)], fmt="o", capsize=3, label=_label(g)
        )
    if all(a > 0 for a, _, _ in pts) and max(a for a, _, _ in pts) / min(a for a, _, _ in pts) > 20:
        ax.set_xscale("log")
    ax.set_xlabel("α (fraction of memory shown per question)")
    ax.set_ylabel("accuracy (%)")
    ax.set_ylim(0, 105)
    ax.grid(alpha=0.3)
    ax.set_title("Accuracy vs memory shown")
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return True


def plot_study(st: dict[str, Any], path: Path) -> bool:
    if not st.get("points"):
        return False
    plt = _plt()
    fig, ax = plt.subplots(figsize=(6.0, 4.2))
    xkey = "sparsification" if st["study"] == "compression" else "coverage"
    for m in sorted({p["method"] for p in st["points"]}):
        pts = sorted((p[xkey], p["accuracy"]) for p in st["points"] if p["method"] == m)
        xs = [x * (100 if xkey == "coverage" else 1) for x, _ in pts]
        ys = [100 * (a.get("mean") or 0.0) for _, a in pts]
        es = [100 * (a.get("std") or 0.0) for _, a in pts]
        ax.errorbar(xs, ys, yerr=es, marker="o", capsize=3, label=m)
    if xkey == "sparsification":
        ax.set_xscale("log")
        ax.set_xlabel("frames per memory (keyframe sparsification, log)")
        ax.set_title("Accuracy vs keyframe rate")
    else:
        ax.set_xlabel("exploration coverage (%)")
        ax.set_title("Accuracy vs coverage")
    ax.set_ylabel("accuracy (%)")
    ax.set_ylim(0, 105)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return True


def find_studies(root: Path) -> list[dict[str, Any]]:
    out = []
    for p in sorted(root.rglob("study.json")) if root.is_dir() else []:
        try:
            out.append(json.loads(p.read_text(encoding="utf-8")))
        except json.JSONDecodeError as e:
            raise InputError(f"{p}: not JSON ({e})") from e
    return out


def write_report(run_dir: str | Path, out: str | Path, thresholds: Thresholds | None = None) -> Path:
    """Write `out` (markdown) and its PNGs in `<out stem>_figs/` beside it; returns the markdown path."""
    root, out = Path(run_dir), Path(out)
    rows = read_rows(root)
    thr = thresholds or _thresholds_of(root)
    summary = summarize(rows, thr)
    studies = find_studies(root)
    figdir = out.parent / f"{out.stem}_figs"
    figdir.mkdir(parents=True, exist_ok=True)
    figs: dict[str, str] = {}
    groups = summary["groups"]
    for name, ok in (("accuracy per category", lambda p: plot_categories(groups, p)),
                     ("error CDFs", lambda p: plot_error_cdfs(groups, rows, p)),
                     ("accuracy vs alpha", lambda p: plot_alpha(groups, p))):  # fmt: skip
        path = figdir / (name.replace(" ", "_") + ".png")
        if ok(path):
            figs[name] = f"{figdir.name}/{path.name}"
    for i, st in enumerate(studies):
        path = figdir / f"study_{st['study']}_{i}.png"
        if plot_study(st, path):
            figs[f"{st['study']} study"] = f"{figdir.name}/{path.name}"
    out.write_text(markdown(summary, rows, figs, studies), encoding="utf-8")
    return out
