"""Reports: markdown tables laid out like the papers' and PNG plots, from one run folder or a
folder of runs (and the studies in it).

Tables: overall (accuracy by the question type's criterion, RAVEN-QA's frame accuracy and the
position accuracy beside it with its threshold, per type, errors), retrieval cost, accuracy per
category, per RAVEN-QA subset and split, NaVQA's per-horizon accuracy and errors, FindingDory's
strict and relaxed accuracy per category, the position-threshold sweep, and each study. Plots:
accuracy per category, error CDFs, position accuracy against the threshold, accuracy against
retrieval cost (alpha, images, tokens: the paper's central comparison) and each study's curve.

Rows are re-scored with the thresholds given (default: the run's own), so a report can apply a
stricter criterion to answers already collected.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from .config import Thresholds
from .metrics import SWEEP_M, group_key, summarize
from .paper import ORIGINS, comparisons
from .runner import read_json, read_rows, run_thresholds

TYPE_COLS = ("position", "time", "duration", "frame", "binary", "text")
HORIZONS = ("short", "medium", "long")


def fmt_pct(d: dict[str, Any] | None, ci: bool = True, n: bool = False) -> str:
    """An accuracy in %: mean (± std over seeds when several), its 95 % bootstrap interval over
    questions in brackets, and (n=) the questions scored when asked for."""
    if not d or d.get("mean") is None:
        return "n/a"
    s = f"{100 * d['mean']:.1f}"
    s += f" ± {100 * d['std']:.1f}" if d.get("seeds", 1) > 1 else ""
    if ci and d.get("ci"):
        s += f" [{100 * d['ci'][0]:.1f}, {100 * d['ci'][1]:.1f}]"
    if n and d.get("questions") is not None:
        s += f" (n={d['questions']})"
    return s


def fmt_num(d: dict[str, Any] | None, digits: int = 2) -> str:
    """A mean ± std (errors, costs)."""
    if not d or d.get("mean") is None:
        return "n/a"
    return f"{d['mean']:.{digits}f} ± {d['std']:.{digits}f}"


def _method(g: dict[str, Any]) -> str:
    return g["method"] + (f" [{g['variant']}]" if g.get("variant") else "")


def _label(g: dict[str, Any]) -> str:
    parts = [_method(g), g["embedder"].rsplit("/", 1)[-1]] + ([g["vlm"]] if g["vlm"] != "-" else [])
    return " | ".join(parts)


def _metres(vals: list[float]) -> str:
    return ", ".join(f"{v:g} m" for v in vals) if vals else "n/a"


def _table(header: list[str], rows: list[list[str]]) -> str:
    out = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    out += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(out)


def _ident(g: dict[str, Any]) -> list[str]:
    return [_method(g), g["embedder"], g["vlm"]]


def _by(g: dict[str, Any], attr: str) -> dict[str, Any]:
    return g.get("by", {}).get(attr, {})


def _breakdown(
    groups: list[dict[str, Any]], attr: str, metric: str, keys: list[str] | None = None
) -> str | None:
    """One table: a line per group, a column per value of `attr`, cells = `metric` there."""
    keys = keys or sorted({k for g in groups for k in _by(g, attr)})
    if not keys or not any(metric in s for g in groups for s in _by(g, attr).values()):
        return None
    body = [_ident(g) + [fmt_pct(_by(g, attr).get(k, {}).get(metric), n=True) for k in keys] for g in groups]
    return _table(["Method", "Embedder", "VLM", *keys], body)


# ------------------------------------------------------------------------------------ sections
def _overall(groups: list[dict[str, Any]]) -> list[str]:
    types = [t for t in TYPE_COLS if any(t in _by(g, "type") for g in groups)]
    frame = any("frame_accuracy" in g for g in groups)
    pos = any("position_accuracy" in g for g in groups)
    head = ["Method", "Embedder", "VLM", "Q", "Seeds", "Accuracy"]
    head += (["Frame acc."] if frame else []) + (["Pos. acc."] if pos else [])
    head += [f"{t.capitalize()} Qs" for t in types] + ["Pos. err (m)", "Time err (min)"]
    body = []
    for g in groups:
        line = _ident(g) + [str(g["questions"]), str(len(g["seeds"])), fmt_pct(g["accuracy"])]
        line += ([fmt_pct(g.get("frame_accuracy"))] if frame else []) + (
            [fmt_pct(g.get("position_accuracy"))] if pos else []
        )
        line += [fmt_pct(_by(g, "type").get(t, {}).get("accuracy")) for t in types]
        line += [fmt_num(g["pos_error_m"]), fmt_num(g["time_error_min"])]
        body.append(line)
    out = ["## Overall", "", _table(head, body), ""]
    release = any("release" in g.get("rules", []) for g in groups)
    notes = ["Accuracy: each question by its type's criterion (below)."]
    if frame:
        notes.append(
            "Frame acc.: the answer names an accepted frame (the paper's target retrieval accuracy, RAVEN-QA's "
            "headline), over every question whose truth names frames"
            + (
                "; release rule (RAVEN-QA rows): the answer's time within 2 s of the time the release gives an "
                "accepted frame, over the questions whose frames it gives a time."
                if release
                else "."
            )
        )
    if pos:
        thr = sorted({v for g in groups for v in g.get("pos_thresholds_m", [])})
        notes.append(
            f"Pos. acc.: the answer's position within {_metres(thr)} of an accepted position, over every "
            "question with positions (the threshold sweep is below)"
            + ("; release rule (RAVEN-QA rows): x, y distance under the threshold." if release else ".")
        )
    if types:
        names = ", ".join(f"{t.capitalize()} Qs" for t in types)
        notes.append(f"{names}: accuracy over the questions of that type, by its own criterion.")
    if notes:
        out += [" ".join(notes), ""]
    return out


def _cost(groups: list[dict[str, Any]]) -> list[str]:
    head = [
        "Method",
        "Embedder",
        "VLM",
        "Accuracy",
        "α",
        "Memories shown/q",
        "Images/q",
        "Tokens/q",
        "Tool calls/q",
        "s/q",
    ]
    body = [
        _ident(g)
        + [
            fmt_pct(g["accuracy"]),
            fmt_num(g["alpha"], 3),
            fmt_num(g["memories_shown"], 1),
            fmt_num(g["images_per_q"], 1),
            fmt_num(g["tokens_per_q"], 0),
            fmt_num(g["tool_calls_per_q"], 1),
            fmt_num(g["seconds_per_q"], 2),
        ]
        for g in groups
    ]
    return [
        "## Retrieval cost",
        "",
        "α = memories shown to the method / memories held (the paper's retrieval efficiency), per question.",
        "",
        _table(head, body),
        "",
    ]


def _breakdowns(groups: list[dict[str, Any]]) -> list[str]:
    out: list[str] = []
    specs = [
        ("category", "accuracy", "Accuracy per category", None),
        ("category", "frame_accuracy", "Frame accuracy per category", None),
        ("category", "position_accuracy", "Position accuracy per category", None),
        ("category", "relaxed", "Relaxed frame accuracy per category (FindingDory's relaxed score)", None),
        ("subset_split", "frame_accuracy", "Frame accuracy per subset and split (RAVEN-QA)", None),
        ("subset_split", "position_accuracy", "Position accuracy per subset and split (RAVEN-QA)", None),
        ("subset", "frame_accuracy", "Frame accuracy per subset", None),
        ("subset", "position_accuracy", "Position accuracy per subset", None),
        ("split", "frame_accuracy", "Frame accuracy per split", None),
        ("split", "position_accuracy", "Position accuracy per split", None),
        (
            "horizon",
            "accuracy",
            "Accuracy per horizon",
            [h for h in HORIZONS if any(h in _by(g, "horizon") for g in groups)],
        ),
    ]
    for attr, metric, title, keys in specs:
        if attr == "subset" and any(_by(g, "subset_split") for g in groups):
            continue  # the subset/split table already says it
        if keys == []:
            continue
        if attr == "category" and metric != "accuracy" and _same_as_accuracy(groups, metric):
            continue  # e.g. FindingDory: every question is a frame question, the table would repeat
        t = _breakdown(groups, attr, metric, keys)
        if t is not None:
            out += [f"## {title}", "", t, ""]
    return out


def _same_as_accuracy(groups: list[dict[str, Any]], metric: str) -> bool:
    """Whether `metric` is every question's own criterion (so its table would repeat accuracy's)."""
    return all(g.get("is_accuracy", {}).get(metric, False) for g in groups)


def _horizon_types(groups: list[dict[str, Any]], thr: dict[str, Any]) -> list[str]:
    """NaVQA's tables: per horizon, descriptive accuracy (binary and text questions together),
    positional error and temporal error (time and duration together), and the paper's accuracy
    conversions: a position within its threshold (NaVQA 15 m), a time within the time threshold."""
    hks = {k for g in groups for k in _by(g, "horizon_kind")}
    horizons = [h for h in HORIZONS if any(k.startswith(h + "/") for k in hks)]
    if len(horizons) < 2:  # one horizon: the overall table says it all
        return []
    pos_m = sorted({v for g in groups for v in g.get("pos_thresholds_m", [])})
    head = [
        "Method",
        "Embedder",
        "VLM",
        "Horizon",
        "Descriptive acc.",
        "Pos. err (m)",
        f"Pos. acc. ≤ {_metres(pos_m)}",
        "Temporal err (min)",
        f"Temporal acc. ≤ {thr['time_s'] / 60:g} min",
    ]
    body = []
    for g in groups:
        for h in horizons:
            by = _by(g, "horizon_kind")
            d, p, t = (by.get(f"{h}/{k}", {}) for k in ("descriptive", "positional", "temporal"))
            body.append(
                _ident(g)
                + [
                    h,
                    fmt_pct(d.get("accuracy"), n=True),
                    fmt_num(p.get("pos_error_m")),
                    fmt_pct(p.get("accuracy"), n=True),
                    fmt_num(t.get("temporal_error_min")),
                    fmt_pct(t.get("accuracy"), n=True),
                ]
            )
    return [
        "## Per horizon: NaVQA's table",
        "",
        "Descriptive: binary and text questions. Temporal: time and duration questions (the duration "
        f"criterion is {thr['duration_s'] / 60:g} min). The accuracy columns are the paper's conversion of the errors.",
        "",
        _table(head, body),
        "",
    ]


def _sweep(groups: list[dict[str, Any]]) -> list[str]:
    gs = [g for g in groups if g.get("pos_sweep")]
    if not gs:
        return []
    thr = gs[0]["pos_sweep"]["thresholds_m"]
    body = [_ident(g) + [fmt_pct(a) for a in g["pos_sweep"]["accuracy"]] for g in gs]
    return [
        "## Position accuracy against the threshold",
        "",
        _table(["Method", "Embedder", "VLM", *[f"≤ {t:g} m" for t in thr]], body),
        "",
    ]


def _names(items: list[str], most: int = 10) -> str:
    shown = "; ".join(items[:most])
    return shown + (f"; and {len(items) - most} more" if len(items) > most else "")


def _notes(groups: list[dict[str, Any]], summary: dict[str, Any]) -> list[str]:
    notes = [f"- `{r['dataset']}`: {r['rule']}." for r in summary.get("time_rules", [])]
    notes += [f"- `{r['dataset']}`: {r['note']}." for r in summary.get("dataset_notes", [])]
    for g in groups:
        errs = g.get("truth_errors") or []
        if errs:
            notes.append(
                f"- {_label(g)}: {len(errs)} question(s) have a truth outside their recording and are not "
                f"scored (truth errors): {_names([f'{q}: {why}' for q, why in errs])}."
            )
        for why, count in (g.get("skipped") or {}).items():
            notes.append(f"- {_label(g)}: {count} question(s) not scored: {why}.")
        if g["not_judged"]:
            notes.append(
                f"- {_label(g)}: {g['not_judged']} text answer(s) not scored: no LLM judge was configured "
                "(run with --judge MODEL)."
            )
        if g["failed"]:
            notes.append(
                f"- {_label(g)}: {g['failed']} answer(s) failed (counted wrong; see `error` in answers.jsonl)."
            )
        if g.get("ran_other"):
            notes.append(
                f"- {_label(g)}: some answers came from another method: {', '.join(g['ran_other'])}."
            )
    return ["## Notes", "", *notes, ""] if notes else []


def _where(w: dict[str, tuple[str, ...]]) -> str:
    """A figure's questions in our fields: `subset irs_hard`, `ep_id ep_91-ep_100 (10)`, `all`."""

    def values(vs: tuple[str, ...]) -> str:
        return vs[0] if len(vs) == 1 else f"{vs[0]}-{vs[-1]} ({len(vs)})"

    return ", ".join(f"{k} {values(vs)}" for k, vs in w.items()) or "all"


def _ours(b: dict[str, Any]) -> str:
    """Our value; an average with the groups' values it is the mean of."""
    if "parts" not in b["ours"]:
        return fmt_pct(b["ours"], n=True)
    parts = ", ".join(f"{g} {fmt_pct(v, ci=False)}" for g, v in b["ours"]["parts"])
    return f"{fmt_pct(b['ours'])} (mean of {parts})"


def paper_lines(rows: list[dict[str, Any]]) -> list[str]:
    """One line per our row that has a published figure beside it, and one for the figures of
    the benchmarks run here that have none (for the console)."""
    shown, missing = comparisons(rows)
    lines = [
        f"{b['paper'].benchmark} {b['paper'].group} ({_where(b['paper'].where)}) {b['method']} | "
        f"{b['embedder']} | {b['vlm']}: ours {_ours(b)}; {b['paper'].theirs}: {b['paper'].label}"
        for b in shown
    ]
    if missing:
        names = ", ".join(sorted({f.benchmark for f, _ in missing}))
        lines.append(
            f"{len(missing)} more published figure(s) for {names} have no value of ours beside them "
            "(the report lists them under 'Published, not run here')"
        )
    return lines


def _sources(figs: list[Any]) -> dict[str, int]:
    return {s: i + 1 for i, s in enumerate(dict.fromkeys(f.source for f in figs))}


def _paper(rows: list[dict[str, Any]]) -> list[str]:
    """Our rows beside the RAVEN authors' published figures for the same benchmark, questions
    and method, and the figures of the benchmarks run here with no value of ours
    (`ravenmem.eval.paper`)."""
    shown, missing = comparisons(rows)
    if not shown and not missing:
        return []
    srcs = _sources([b["paper"] for b in shown] + [f for f, _ in missing])
    out = ["## Beside the paper", ""]
    if shown:
        body = [
            [p.benchmark, p.group, _where(p.where), b["method"], b["embedder"], b["vlm"], _ours(b), p.shown]
            + [f"{ORIGINS[p.origin]}: {p.place} [{srcs[p.source]}]", p.who]
            for b in shown
            for p in [b["paper"]]
        ]
        head = ["Benchmark", "The paper's group", "Our questions", "Method", "Embedder", "VLM", "Ours %"]
        head += ["The paper's %", "Published in", "Model, encoder (the paper's)"]
        out += [_table(head, body), ""]
        out += [
            "The paper's columns are the RAVEN authors' published figure for the same benchmark, "
            "questions and method (Embedder Only = embedder-only, ReMEmbR = caption, VLM Only = "
            "vlm-only, Ours = raven), with the model and encoder as the source names them; ours is the "
            "same metric over exactly these rows, by our own model and encoder, so the two differ in "
            "model as well as in method. An average is the mean of the groups' values, as the chart's "
            "Average bars are (not a pooled accuracy).",
            "",
        ]
    if missing:
        body = [
            [f.benchmark, f.group, _where(f.where), f.method, f.metric, f.shown]
            + [f"{ORIGINS[f.origin]}: {f.place} [{srcs[f.source]}]", why]
            for f, why in missing
        ]
        head = ["Benchmark", "The paper's group", "Our questions", "Method", "Metric", "The paper's %"]
        out += [
            "### Published, not run here",
            "",
            _table(head + ["Published in", "Why no value of ours"], body),
            "",
        ]
    notes = sorted(
        {f"{p.group}: {p.note}." for p in [b["paper"] for b in shown] + [f for f, _ in missing] if p.note}
    )
    out += ["Sources: " + "; ".join(f"[{i}] {s}" for s, i in srcs.items()) + ".", ""]
    out += [" ".join(notes), ""] if notes else []
    return out


def _study_value(st: dict[str, Any], p: dict[str, Any]) -> str:
    if st["study"] == "consolidation":
        return str(p["strategy"]) + ("" if p.get("budget") is None else f" {p['budget']}")
    if st["study"] == "compression":
        return str(p["stride"])
    if st["study"] == "coverage":
        return f"{100 * p['coverage']:.0f}%"
    return str(p["value"])


def _study(st: dict[str, Any]) -> list[str]:
    title = f"## {st['study'].capitalize()} study"
    if st["study"] == "embedders":
        head = ["Embedder", "Direction", "mAP", "mAP small objects", f"P@{st['k']}", "Images/s"]
        body = [
            [
                p["embedder"],
                p["direction"],
                f"{p['mAP']:.3f}",
                f"{p['mAP_small']:.3f}",
                f"{p['P@k']:.3f}",
                f"{p['images_per_s'] or 0:.1f}",
            ]
            for p in st["points"]
        ]
        body += [["random ranking", d, f"{c:.3f}", "", "", ""] for d, c in st["chance"].items()]
        return [
            f"{title} (`{st['labels']}`, {st['frames']} frames, {len(st['objects'])} objects)",
            "",
            _table(head, body),
            "",
        ]
    first = {"compression": "Stride", "coverage": "Coverage", "consolidation": "Strategy / budget"}.get(
        st["study"], st.get("option", "value")
    )
    head = [
        first,
        "Method",
        "Accuracy",
        "Frame acc.",
        "Pos. acc.",
        "α",
        "Images/q",
        "Tokens/q",
        "Tool calls/q",
    ]
    if st["study"] in ("compression", "coverage"):
        head[1:1] = ["Memories", "Frames"]
    elif st["study"] == "consolidation":
        head[1:1] = ["Memories"]
    body = []
    for p in st["points"]:
        line = [_study_value(st, p)]
        if st["study"] in ("compression", "coverage"):
            line += [str(p["memories"]), str(p["frames"])]
        elif st["study"] == "consolidation":
            line += [str(p["memories"])]
        line += [
            p["method"],
            fmt_pct(p["accuracy"]),
            fmt_pct(p.get("frame_accuracy")),
            fmt_pct(p.get("position_accuracy")),
        ]
        line += [
            fmt_num(p["alpha"], 3),
            fmt_num(p["images_per_q"], 1),
            fmt_num(p["tokens_per_q"], 0),
            fmt_num(p["tool_calls_per_q"], 1),
        ]
        body.append(line)
    return [f"{title} (`{st.get('dataset', '')}`)", "", _table(head, body), ""]


def markdown(
    summary: dict[str, Any], rows: list[dict[str, Any]], figs: dict[str, str], studies: list[dict[str, Any]]
) -> str:
    groups = summary["groups"]
    thr = summary["thresholds"]
    lines = ["# Evaluation report", ""]
    if rows:
        datasets = sorted({r.get("dataset", "") for r in rows})
        used = sorted({float(r["score"]["threshold_m"]) for r in rows if "threshold_m" in r["score"]})
        lines += [
            f"{len(rows)} answers, {len({r['qid'] for r in rows})} questions, dataset(s): "
            + ", ".join(f"`{d}`" for d in datasets),
            "",
            "Accuracy in % (mean ± std over seeds where there are several) with its 95 % bootstrap interval "
            "over questions in brackets; n = questions scored; errors mean ± std over answered "
            f"questions. Position threshold(s): {_metres(used)}; time {thr['time_s'] / 60:g} min, "
            f"duration {thr['duration_s'] / 60:g} min. Scoring rule: {thr.get('scoring', 'paper')}"
            + (
                " (the benchmark release's own scorer where it differs: RAVEN-QA)"
                if thr.get("scoring") == "release"
                else " (the papers' criteria)"
            )
            + ".",
            "",
            "Clock times: "
            + "; ".join(sorted({str(r.get("zone") or "UTC (recording clock)") for r in rows}))
            + ".",
            "",
        ]
        lines += _overall(groups) + _cost(groups) + _breakdowns(groups) + _horizon_types(groups, thr)
        lines += _sweep(groups) + _paper(rows) + _notes(groups, summary)
    for st in studies:
        lines += _study(st)
    if figs:
        lines += ["## Figures", ""] + [f"![{name}]({rel})" for name, rel in figs.items()] + [""]
    return "\n".join(lines)


# ------------------------------------------------------------------------------------ plots
def _plt() -> Any:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _save(fig: Any, path: Path) -> bool:
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    _plt().close(fig)
    return True


def _legend(ax: Any) -> None:
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0))


def plot_categories(groups: list[dict[str, Any]], path: Path) -> bool:
    cats = sorted({k for g in groups for k in _by(g, "category")})
    if not cats:
        return False
    plt = _plt()
    fig, ax = plt.subplots(figsize=(max(6.0, 1.3 * len(cats) + 2) + 2.5, 4.2))
    w = 0.8 / len(groups)
    x = np.arange(len(cats))
    for i, g in enumerate(groups):
        accs = [_by(g, "category").get(c, {}).get("accuracy", {}) for c in cats]
        vals = [100 * (a.get("mean") or 0.0) for a in accs]
        errs = [100 * (a.get("std") or 0.0) for a in accs]
        ax.bar(x + (i - (len(groups) - 1) / 2) * w, vals, w, yerr=errs, capsize=3, label=_label(g))
    ax.set_xticks(x, cats, rotation=20, ha="right")
    ax.set_ylabel("accuracy (%)")
    ax.set_ylim(0, 105)
    ax.set_title("Accuracy per category")
    _legend(ax)
    ax.grid(axis="y", alpha=0.3)
    return _save(fig, path)


def _errors(rows: list[dict[str, Any]], g: dict[str, Any], key: str) -> np.ndarray:
    gk = (g["method"], g["embedder"], g["vlm"], g.get("variant") or "")
    return np.sort([r["score"][key] for r in rows if group_key(r) == gk and key in r["score"]])


def plot_error_cdfs(groups: list[dict[str, Any]], rows: list[dict[str, Any]], path: Path) -> bool:
    kinds = [("pos_error_m", "position error (m)", 1.0), ("time_error_s", "time error (min)", 1 / 60)]
    have = [k for k in kinds if any(k[0] in r["score"] for r in rows)]
    if not have:
        return False
    plt = _plt()
    fig, axes = plt.subplots(1, len(have), figsize=(5.5 * len(have), 4.0), squeeze=False)
    for ax, (key, title, scale) in zip(axes[0], have):
        for g in groups:
            errs = _errors(rows, g, key) * scale
            if errs.size:
                ax.step(errs, np.arange(1, errs.size + 1) / errs.size, where="post", label=_label(g))
        ax.set_xlabel(title)
        ax.set_ylabel("fraction of answered questions")
        ax.set_ylim(0, 1.02)
        ax.grid(alpha=0.3)
        ax.set_title(f"CDF of {title}")
        ax.legend(fontsize=8)
    return _save(fig, path)


def plot_position_sweep(groups: list[dict[str, Any]], rows: list[dict[str, Any]], path: Path) -> bool:
    """Position accuracy as the threshold grows (all seeds pooled; a missing position never counts)."""
    gs = [g for g in groups if g.get("pos_sweep")]
    if not gs:
        return False
    plt = _plt()
    fig, ax = plt.subplots(figsize=(8.5, 4.2))
    top = max(SWEEP_M[-1], *(v for g in gs for v in g.get("pos_thresholds_m", [])))
    xs = np.linspace(0, top, 400)
    for g in gs:
        gk = (g["method"], g["embedder"], g["vlm"], g.get("variant") or "")
        pos = [r for r in rows if group_key(r) == gk and "pos_correct" in r["score"]]
        errs = np.array([r["score"].get("pos_error_m", np.inf) for r in pos], dtype=float)
        ax.plot(xs, [100 * float(np.mean(errs <= x)) for x in xs], label=_label(g))
    for v in sorted({v for g in gs for v in g.get("pos_thresholds_m", [])}):
        ax.axvline(v, color="grey", ls="--", lw=0.8)
    ax.set_xlabel("position threshold (m); dashed: the threshold of the Pos. acc. column")
    ax.set_ylabel("position accuracy (%)")
    ax.set_ylim(0, 105)
    ax.grid(alpha=0.3)
    ax.set_title("Position accuracy against the threshold")
    _legend(ax)
    return _save(fig, path)


COSTS = (
    ("alpha", "α (memories shown / memories held)"),
    ("images_per_q", "images sent per question"),
    ("tokens_per_q", "tokens per question"),
)


def plot_cost(groups: list[dict[str, Any]], path: Path) -> bool:
    """Accuracy against retrieval cost, one point per method (a line through a study's settings)."""
    pts = [g for g in groups if g["accuracy"]["mean"] is not None and g["alpha"]["mean"] is not None]
    if not pts:
        return False
    plt = _plt()
    fig, axes = plt.subplots(1, len(COSTS), figsize=(15.0, 4.4), squeeze=False)
    lines: dict[tuple[str, str, str], list[dict[str, Any]]] = {}
    for g in pts:
        lines.setdefault((g["method"], g["embedder"], g["vlm"]), []).append(g)
    for ax, (key, title) in zip(axes[0], COSTS):
        xs_all = []
        for (method, emb, vlm), gs in sorted(lines.items()):
            gs = sorted(gs, key=lambda g: g[key]["mean"] or 0.0)
            xs = [g[key]["mean"] or 0.0 for g in gs]
            ys = [100 * g["accuracy"]["mean"] for g in gs]
            es = [100 * (g["accuracy"]["std"] or 0.0) for g in gs]
            label = " | ".join([method, emb.rsplit("/", 1)[-1]] + ([vlm] if vlm != "-" else []))
            ax.errorbar(xs, ys, yerr=es, marker="o", capsize=3, label=label)
            xs_all += xs
        pos = [x for x in xs_all if x > 0]
        if pos and len(pos) == len(xs_all) and max(pos) / min(pos) > 20:
            ax.set_xscale("log")
        ax.set_xlabel(title)
        ax.set_ylabel("accuracy (%)")
        ax.set_ylim(0, 105)
        ax.grid(alpha=0.3)
    axes[0][0].set_title("Accuracy against retrieval cost")
    _legend(axes[0][-1])
    return _save(fig, path)


def plot_study(st: dict[str, Any], path: Path) -> bool:
    if not st.get("points"):
        return False
    plt = _plt()
    if st["study"] == "embedders":
        return _plot_embedders(st, path)
    if st["study"] == "consolidation":
        return _plot_consolidation(st, path)
    fig, ax = plt.subplots(figsize=(6.5, 4.2))
    xkey = {"compression": "sparsification", "coverage": "coverage"}.get(st["study"], "value")
    raw = [p[xkey] for p in st["points"]]
    numeric = all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in raw)
    order = list(dict.fromkeys(str(v) for v in raw))
    for m in sorted({p["method"] for p in st["points"]}):
        ps = [p for p in st["points"] if p["method"] == m]
        ps.sort(key=lambda p: p[xkey] if numeric else order.index(str(p[xkey])))
        xs = [
            p[xkey] * (100 if xkey == "coverage" else 1) if numeric else order.index(str(p[xkey])) for p in ps
        ]
        ys = [100 * (p["accuracy"].get("mean") or 0.0) for p in ps]
        es = [100 * (p["accuracy"].get("std") or 0.0) for p in ps]
        ax.errorbar(xs, ys, yerr=es, marker="o", capsize=3, label=m)
    if xkey == "sparsification":
        ax.set_xscale("log")
        ax.set_xlabel("frames per memory (keyframe sparsification, log)")
        ax.set_title("Accuracy vs keyframe rate")
    elif xkey == "coverage":
        ax.set_xlabel("exploration coverage (%)")
        ax.set_title("Accuracy vs coverage")
    else:
        if not numeric:
            ax.set_xticks(range(len(order)), order)
        ax.set_xlabel(st.get("option", "value"))
        ax.set_title(f"Accuracy vs {st.get('option', 'value')} ({st['study']} study)")
    ax.set_ylabel("accuracy (%)")
    ax.set_ylim(0, 105)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    return _save(fig, path)


def _plot_consolidation(st: dict[str, Any], path: Path) -> bool:
    """Accuracy against memories kept (log), one line per method and strategy; the full memory
    is the rightmost point of every line."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(6.5, 4.2))
    full = {p["method"]: p for p in st["points"] if p["strategy"] == "full"}
    styles = {"consolidate": "-", "uniform": "--"}
    for m in sorted({p["method"] for p in st["points"]}):
        for strategy in [s for s in styles if any(p["strategy"] == s for p in st["points"])]:
            ps = [p for p in st["points"] if p["method"] == m and p["strategy"] == strategy]
            ps += [full[m]] if m in full else []
            ps.sort(key=lambda p: p["memories"])
            ys = [100 * (p["accuracy"].get("mean") or 0.0) for p in ps]
            ax.plot([p["memories"] for p in ps], ys, styles[strategy], marker="o", label=f"{m}, {strategy}")
    ax.set_xscale("log")
    ax.set_xlabel("memories kept (log)")
    ax.set_ylabel("accuracy (%)")
    ax.set_ylim(0, 105)
    ax.set_title("Accuracy vs memory budget (consolidation study)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    return _save(fig, path)


def _plot_embedders(st: dict[str, Any], path: Path) -> bool:
    plt = _plt()
    embs = list(dict.fromkeys(p["embedder"] for p in st["points"]))
    dirs = list(st["chance"])
    fig, ax = plt.subplots(figsize=(max(6.0, 1.6 * len(embs) + 2), 4.2))
    w = 0.8 / len(dirs)
    x = np.arange(len(embs))
    for i, d in enumerate(dirs):
        vals = [
            next((p["mAP"] for p in st["points"] if p["embedder"] == e and p["direction"] == d), 0.0)
            for e in embs
        ]
        ax.bar(x + (i - (len(dirs) - 1) / 2) * w, vals, w, label=f"{d} (random {st['chance'][d]:.2f})")
    ax.set_xticks(x, [e.rsplit("/", 1)[-1] for e in embs], rotation=15, ha="right")
    ax.set_ylabel("mAP")
    ax.set_ylim(0, 1.05)
    ax.set_title("Retrieval quality per embedder")
    ax.legend(fontsize=8)
    ax.grid(axis="y", alpha=0.3)
    return _save(fig, path)


def find_studies(root: Path) -> list[dict[str, Any]]:
    return [read_json(p) for p in (sorted(root.rglob("study.json")) if root.is_dir() else [])]


def write_report(run_dir: str | Path, out: str | Path, thresholds: Thresholds | None = None) -> Path:
    """Write `out` (markdown) and its PNGs in `<out stem>_figs/` beside it; returns the markdown path."""
    root, out = Path(run_dir), Path(out)
    studies = find_studies(root)
    only_embedders = bool(studies) and all(st["study"] == "embedders" for st in studies)
    rows = [] if only_embedders else read_rows(root)
    summary = summarize(rows, thresholds or run_thresholds(root))
    figdir = out.parent / f"{out.stem}_figs"
    figdir.mkdir(parents=True, exist_ok=True)
    figs: dict[str, str] = {}
    groups = summary["groups"]
    plots: list[tuple[str, Callable[[Path], bool]]] = [
        ("accuracy per category", lambda p: plot_categories(groups, p)),
        ("error CDFs", lambda p: plot_error_cdfs(groups, rows, p)),
        ("position accuracy vs threshold", lambda p: plot_position_sweep(groups, rows, p)),
        ("accuracy vs retrieval cost", lambda p: plot_cost(groups, p)),
    ]
    for name, draw in plots if rows else []:
        path = figdir / (name.replace(" ", "_") + ".png")
        if draw(path):
            figs[name] = f"{figdir.name}/{path.name}"
    for i, st in enumerate(studies):
        path = figdir / f"study_{st['study']}_{i}.png"
        if plot_study(st, path):
            figs[f"{st['study']} study"] = f"{figdir.name}/{path.name}"
    out.write_text(markdown(summary, rows, figs, studies), encoding="utf-8")
    return out
