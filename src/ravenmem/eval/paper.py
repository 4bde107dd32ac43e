"""The published figures beside ours: `ravenmem eval report` shows, for each of our rows, the
figure the RAVEN authors published for the same benchmark, split and method, when they did.

The figures live in `paper_figures.json` beside this module, each with its source (where it was
read, the sentence it came from) and the model and encoder that produced it (null when the
source does not name them). A figure is matched to our rows by benchmark (the dataset kind),
method, and the question fields in `where` (subset, split, horizon...); our side is the same
metric over exactly those rows, with its interval. Nothing here is estimated: a benchmark with no
published figure gets no paper column.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from importlib.resources import files
from typing import Any

from ..errors import InputError
from .metrics import seed_accuracy

FIGURES = "paper_figures.json"
METRICS = ("accuracy",)  # the per-question criterion `score.correct` (the report's Accuracy column)


@dataclass(frozen=True)
class Figure:
    benchmark: str
    where: dict[str, str]
    method: str
    metric: str
    value: float
    bound: str
    model: str | None
    encoder: str | None
    source: str
    quote: str
    note: str

    @property
    def label(self) -> str:
        who = ", ".join(
            [f"model {self.model}" if self.model else "model not named"]
            + ([f"encoder {self.encoder}"] if self.encoder else [])
        )
        return f"{self.bound + ' ' if self.bound else ''}{self.value:g} % ({who})"


def load_figures(text: str | None = None) -> list[Figure]:
    """The published figures (the packaged file, or `text` in its format); a malformed entry is
    a one-line error naming it."""
    raw = text if text is not None else files("ravenmem.eval").joinpath(FIGURES).read_text(encoding="utf-8")
    try:
        items = json.loads(raw)["figures"]
        out = [
            Figure(
                benchmark=str(d["benchmark"]),
                where={str(k): str(v) for k, v in (d.get("where") or {}).items()},
                method=str(d["method"]),
                metric=str(d["metric"]),
                value=float(d["value"]),
                bound=str(d.get("bound") or ""),
                model=d.get("model"),
                encoder=d.get("encoder"),
                source=str(d["source"]),
                quote=str(d.get("quote") or ""),
                note=str(d.get("note") or ""),
            )
            for d in items
        ]
    except (ValueError, KeyError, TypeError) as e:
        raise InputError(f"{FIGURES}: not a list of published figures ({e})") from e
    bad = [f.metric for f in out if f.metric not in METRICS]
    if bad:
        raise InputError(f"{FIGURES}: unknown metric(s) {', '.join(bad)} (known: {', '.join(METRICS)})")
    return out


def _matches(row: dict[str, Any], f: Figure) -> bool:
    kind = str(row.get("dataset", "")).partition(":")[0]
    q = row.get("question", {})
    return (
        kind == f.benchmark
        and row.get("method") == f.method
        and all(str(q.get(k) or "") == v for k, v in f.where.items())
    )


def beside(rows: list[dict[str, Any]], figures: list[Figure] | None = None) -> list[dict[str, Any]]:
    """One line per (figure, our method | embedder | VLM) that has rows for it: our value with its
    interval and question count, the paper's figure and its source."""
    out = []
    for f in figures if figures is not None else load_figures():
        groups: dict[tuple[str, str, str], list[dict[str, Any]]] = {}
        for r in rows:
            if _matches(r, f):
                key = (str(r["method"]), str(r.get("embedder") or "-"), str(r.get("vlm") or "-"))
                groups.setdefault(key, []).append(r)
        for (method, emb, vlm), rs in sorted(groups.items()):
            out.append(
                {
                    "benchmark": f.benchmark,
                    "where": f.where,
                    "method": method,
                    "embedder": emb,
                    "vlm": vlm,
                    "ours": seed_accuracy(rs),
                    "paper": f,
                }
            )
    return out
