"""The published figures beside ours: `ravenmem eval report` shows, for each of our rows, the
figure the RAVEN authors published for the same benchmark, questions and method, when they did.

The figures live in `paper_figures.json` beside this module, each with its source: a sentence of
the authors' project page (`origin` "text", with its quote) or a bar of its Benchmark Results
chart (`origin` "figure": the image file, panel, bar group and legend entry, the value printed
above the bar). The chart names neither the VLM nor the encoder, so neither do we: its figures say
"not named on the figure" rather than guessing from the release's examples.

A figure is matched to our rows by benchmark (the dataset kind), method, and the question fields
in `where` (subset, ep_id, NaVQA's `kind`...; a list means any of those values); our side is the
same metric over exactly those rows, with its interval. An `average_of` figure is the mean of
other groups' figures (the chart's "Average" bars: a mean of the groups, not a pooled
accuracy), so ours is the mean of our values for the same groups, shown only when we have every
one of them. A metric we do not compute (FindingDory's memory efficiency) is never put beside a
value of ours; it, and every figure of a benchmark we ran that has no matching rows, is listed as
published, not run here. Nothing here is estimated.
"""

from __future__ import annotations

import json
from collections.abc import Iterable
from dataclasses import dataclass
from importlib.resources import files
from typing import Any

import numpy as np

from ..errors import InputError
from .config import RAVEN_QA
from .metrics import KINDS, group_key, seed_accuracy

FIGURES = "paper_figures.json"
# metric -> the score key our rows hold it in (`accuracy`: the report's Accuracy column, each
# question by its type's criterion)
METRICS = {"accuracy": "correct"}
# metrics the paper publishes that ravenmem does not compute: listed, never compared
PUBLISHED_ONLY = {
    "memory_efficiency": "ravenmem does not compute this quantity (the page does not define it; "
    "α, memories shown / memories held, is not it), so no value of ours is put beside it",
}
ORIGINS = {"figure": "RAVEN authors' project page figure", "text": "RAVEN authors' project page text"}
UNNAMED = {"figure": "not named on the figure", "text": "not named in the text"}


@dataclass(frozen=True)
class Figure:
    benchmark: str
    group: str  # the paper's label for these questions (the chart's bar group)
    where: dict[str, tuple[str, ...]]
    method: str
    metric: str
    value: float
    bound: str
    origin: str  # "figure" | "text"
    model: str | None
    encoder: str | None
    source: str
    file: str
    panel: str
    legend: str
    axis: str
    quote: str
    note: str
    average_of: tuple[str, ...]

    @property
    def theirs(self) -> str:
        """Whose figure this is, as every line that shows it says."""
        return f"the paper's ({ORIGINS[self.origin]})"

    @property
    def who(self) -> str:
        """The model and encoder that produced the figure, as its source names them."""
        unnamed = UNNAMED[self.origin]
        return f"model: {self.model or unnamed}, encoder: {self.encoder or unnamed}"

    @property
    def shown(self) -> str:
        return f"{self.bound + ' ' if self.bound else ''}{self.value:.1f} %"  # as the chart prints it

    @property
    def label(self) -> str:
        return f"{self.shown} ({self.who})"

    @property
    def place(self) -> str:
        """Where on the page it was read: the chart's panel, bar group and bar, or the text."""
        if self.origin == "figure":
            return f"{self.panel}, {self.group}, bar {self.legend}"
        return f'"{self.quote}"'


def _where(raw: Any) -> dict[str, tuple[str, ...]]:
    if not isinstance(raw, dict):
        raise TypeError(f"where must be an object, got {raw!r}")
    return {str(k): tuple(map(str, v)) if isinstance(v, list) else (str(v),) for k, v in raw.items()}


def _figure(d: dict[str, Any]) -> Figure:
    return Figure(
        benchmark=str(d["benchmark"]),
        group=str(d.get("group") or ""),
        where=_where(d.get("where") or {}),
        method=str(d["method"]),
        metric=str(d["metric"]),
        value=float(d["value"]),
        bound=str(d.get("bound") or ""),
        origin=str(d.get("origin") or "text"),
        model=d.get("model"),
        encoder=d.get("encoder"),
        source=str(d["source"]),
        file=str(d.get("file") or ""),
        panel=str(d.get("panel") or ""),
        legend=str(d.get("legend") or ""),
        axis=str(d.get("axis") or ""),
        quote=str(d.get("quote") or ""),
        note=str(d.get("note") or ""),
        average_of=tuple(map(str, d.get("average_of") or ())),
    )


def _check(out: list[Figure]) -> None:
    """Known metrics and origins; an average names groups that are figures of its own kind."""
    bad = [f.metric for f in out if f.metric not in METRICS and f.metric not in PUBLISHED_ONLY]
    if bad:
        known = ", ".join([*METRICS, *PUBLISHED_ONLY])
        raise InputError(f"{FIGURES}: unknown metric(s) {', '.join(bad)} (known: {known})")
    odd = [f.origin for f in out if f.origin not in ORIGINS]
    if odd:
        raise InputError(f"{FIGURES}: unknown origin(s) {', '.join(odd)} (known: {', '.join(ORIGINS)})")
    for f in out:
        missing = [g for g in f.average_of if not parts_of(f, out, g)]
        if missing:
            raise InputError(
                f"{FIGURES}: {f.benchmark} {f.group} {f.method} averages group(s) with no figure: "
                + ", ".join(missing)
            )


def load_figures(text: str | None = None) -> list[Figure]:
    """The published figures (the packaged file, or `text` in its format); a malformed file or
    entry is a one-line error naming it."""
    raw = text if text is not None else files("ravenmem.eval").joinpath(FIGURES).read_text(encoding="utf-8")
    try:
        out = [_figure(d) for d in json.loads(raw)["figures"]]
    except (ValueError, KeyError, TypeError, AttributeError) as e:
        raise InputError(f"{FIGURES}: not a list of published figures ({type(e).__name__}: {e})") from e
    _check(out)
    return out


def parts_of(f: Figure, figures: Iterable[Figure], group: str) -> list[Figure]:
    """The figures of `group` that the average `f` takes (same benchmark, method and metric)."""
    return [
        p
        for p in figures
        if p.group == group
        and (p.benchmark, p.method, p.metric, p.origin) == (f.benchmark, f.method, f.metric, f.origin)
    ]


# ------------------------------------------------------------------------------------ matching
def benchmark_of(row: dict[str, Any]) -> str:
    """The benchmark a row belongs to: its dataset kind, RAVEN-QA's aliases as one."""
    kind = str(row.get("dataset", "")).partition(":")[0]
    return "raven-qa" if kind in RAVEN_QA else kind


def field(row: dict[str, Any], key: str) -> str:
    """A question field a figure's `where` names: `kind` is NaVQA's grouping of question types
    (descriptive, positional, temporal), other keys the question's own field, else its meta."""
    q = row.get("question", {})
    if key == "kind":
        return KINDS.get(str(q.get("type")), "")
    value = q.get(key) if key in q else (q.get("meta") or {}).get(key)
    return str(value or "")


def _matches(row: dict[str, Any], f: Figure) -> bool:
    return (
        benchmark_of(row) == f.benchmark
        and row.get("method") == f.method
        and all(field(row, k) in vs for k, vs in f.where.items())
    )


Key = tuple[str, str, str]


def _ours(rows: list[dict[str, Any]], f: Figure) -> dict[Key, dict[str, Any]]:
    """Our value of `f`'s metric over the rows it covers, per (method [variant], embedder, VLM)."""
    groups: dict[Key, list[dict[str, Any]]] = {}
    for r in rows:
        if _matches(r, f):
            method, emb, vlm, variant = group_key(r)  # a study's settings stay apart, as in the tables
            groups.setdefault((method + (f" [{variant}]" if variant else ""), emb, vlm), []).append(r)
    found = {k: seed_accuracy(rs, METRICS[f.metric]) for k, rs in groups.items()}
    return {k: v for k, v in found.items() if v.get("mean") is not None}


def _average(rows: list[dict[str, Any]], f: Figure, figures: list[Figure]) -> dict[Key, dict[str, Any]]:
    """The mean of our values for every group `f` averages, per (method, embedder, VLM) that has
    them all (the paper's Average: a mean of the groups, not a pooled accuracy)."""
    per_group = [(g, _ours(rows, parts_of(f, figures, g)[0])) for g in f.average_of]
    keys = set.intersection(*(set(v) for _, v in per_group)) if per_group else set()
    out = {}
    for k in keys:
        parts = [(g, v[k]) for g, v in per_group]
        mean = float(np.mean([p["mean"] for _, p in parts]))
        out[k] = {"mean": mean, "seeds": 1, "ci": None, "questions": None, "parts": parts}
    return out


def comparisons(
    rows: list[dict[str, Any]], figures: list[Figure] | None = None
) -> tuple[list[dict[str, Any]], list[tuple[Figure, str]]]:
    """(one entry per figure and our (method, embedder, VLM) that has rows for it: our value and
    the paper's figure; the figures of the benchmarks run here with no value of ours beside them,
    each with the reason)."""
    figs = figures if figures is not None else load_figures()
    run = {benchmark_of(r) for r in rows}
    shown: list[dict[str, Any]] = []
    missing: list[tuple[Figure, str]] = []
    for f in figs:
        if f.benchmark not in run:
            continue
        if f.metric in PUBLISHED_ONLY:
            missing.append((f, PUBLISHED_ONLY[f.metric]))
            continue
        ours = _average(rows, f, figs) if f.average_of else _ours(rows, f)
        for (method, emb, vlm), value in sorted(ours.items()):
            shown.append({"paper": f, "method": method, "embedder": emb, "vlm": vlm, "ours": value})
        if not ours:
            why = f"no rows of ours for method {f.method} on these questions"
            if f.average_of:
                why = f"needs rows of ours for method {f.method} in every group it averages ({', '.join(f.average_of)})"
            missing.append((f, why))
    return shown, missing


def beside(rows: list[dict[str, Any]], figures: list[Figure] | None = None) -> list[dict[str, Any]]:
    """The figures with a value of ours beside them (`comparisons`' first part)."""
    return comparisons(rows, figures)[0]
