"""`ravenmem eval report` shows the RAVEN authors' published figure beside our row for the same
benchmark, questions and method, labelled as theirs with its source and the model that produced
it (issue 28): the project page's text and every bar of its Benchmark Results chart."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from ravenmem.agent.base import METHODS
from ravenmem.errors import InputError
from ravenmem.eval.datasets import load_dataset
from ravenmem.eval.metrics import KINDS
from ravenmem.eval.paper import Figure, comparisons, load_figures, parts_of
from tests.agent.scripted_server import ScriptedModel
from tests.eval.eval_helpers import plugin_site, rm
from tests.eval.release_files import write_findingdory_release
from tests.eval.release_layouts import navqa_policy, write_raven_navqa, write_raven_qa_release

EMB = ["--embedder", "test-color-eval", "--thumb-size", "32", "--workers", "1"]
CHART = "ravenmem/ravenmem.github.io: static/images/raven_findingdory_navqa.jpg"
THEIRS = "the paper's (RAVEN authors' project page figure)"
UNNAMED = "(model: not named on the figure, encoder: not named on the figure)"


def _fig(figures: list[Figure], bench: str, group: str, method: str, metric: str = "accuracy") -> Figure:
    (f,) = [
        f
        for f in figures
        if (f.benchmark, f.group, f.method, f.metric, f.origin) == (bench, group, method, metric, "figure")
    ]
    return f


def test_every_published_figure_names_its_source() -> None:
    figures = load_figures()
    text = [f for f in figures if f.origin == "text"]
    chart = [f for f in figures if f.origin == "figure"]
    assert all(f.source.startswith("https://ravenmem.github.io/") for f in figures)
    assert text and all(f"{f.value:g}%" in f.quote for f in text)  # the figure is in its quote
    # 4 bars x 5 groups (RAVEN-QA), 4 x 3 + 3 x 2 (FindingDory, two N/A), 3 x 5 (NaVQA, Embedder Only N/A)
    assert len(chart) == 20 + 18 + 15
    assert all(
        f.file == CHART
        and f.panel
        and f.group
        and f.legend
        and f.axis
        and f.model is None
        and f.encoder is None
        for f in chart
    )
    assert {f.method for f in figures} <= set(METHODS.names())  # each legend entry is one of our methods
    qa_real = _fig(figures, "raven-qa", "Real Robot Deploy", "raven")
    assert qa_real.value == 92.4 and qa_real.where == {"subset": ("real_world",)} and qa_real.legend == "Ours"
    assert _fig(figures, "raven-qa", "Human-Ego (Hard)", "raven").where == {"subset": ("irs_hard",)}
    assert _fig(figures, "raven-qa", "Human-Ego (Simple)", "caption").legend == "ReMEmbR"
    assert _fig(figures, "navqa", "Positional Accuracy", "vlm-only").where == {"kind": ("positional",)}
    long = _fig(figures, "findingdory", "High-Level Success (Long)", "raven")
    assert long.value == 32.2 and long.where["ep_id"] == tuple(f"ep_{i}" for i in range(91, 101))
    assert (
        _fig(figures, "findingdory", "Memory Efficiency (Long)", "raven", "memory_efficiency").value == 13.5
    )
    # every Average bar is the mean of the groups it averages, as printed (one decimal)
    averages = [f for f in chart if f.average_of]
    assert len(averages) == 4 + 4 + 3
    for f in averages:
        parts = [parts_of(f, figures, g)[0].value for g in f.average_of]
        assert abs(float(np.mean(parts)) - f.value) <= 0.05 + 1e-9, f


def _one(**over: Any) -> str:
    d = {"benchmark": "navqa", "method": "raven", "metric": "accuracy", "value": 1, "source": "x"} | over
    return json.dumps({"figures": [d]})


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("figures: none", "paper_figures.json: not a list of published figures (JSONDecodeError"),
        ('{"figures": [{"benchmark": "navqa"}]}', "not a list of published figures (KeyError: 'method')"),
        (_one(value="high"), "not a list of published figures (ValueError"),
        (_one(where="all"), "not a list of published figures (TypeError: where must be an object"),
        (_one(metric="vibes"), "unknown metric(s) vibes (known: accuracy, memory_efficiency)"),
        (_one(origin="rumour"), "unknown origin(s) rumour (known: figure, text)"),
        (
            _one(group="Average", average_of=["Nowhere"]),
            "navqa Average raven averages group(s) with no figure: Nowhere",
        ),
    ],
)
def test_a_malformed_figures_file_is_one_line(text: str, message: str) -> None:
    with pytest.raises(InputError) as e:
        load_figures(text)
    assert message in str(e.value) and "\n" not in str(e.value)


def _row(kind: str, method: str, qid: str, correct: bool | None, **question: Any) -> dict[str, Any]:
    q = {"type": "frame", "subset": "", "split": ""} | question
    return {
        "dataset": f"{kind}:/data",
        "method": method,
        "embedder": "emb",
        "vlm": "vlm",
        "qid": qid,
        "seed": 0,
        "question": q,
        "score": {"correct": correct},
    }


def test_an_average_is_the_mean_of_the_groups_not_a_pooled_accuracy() -> None:
    right = {
        "habitat_sim": [True],
        "real_world": [False, False, False],
        "irs": [True],
        "irs_hard": [True, False],
    }
    rows = [
        # both of RAVEN-QA's dataset names are the one benchmark
        _row("ravenqa" if s == "irs" else "raven-qa", "raven", f"{s}{i}", c, subset=s)
        for s, cs in right.items()
        for i, c in enumerate(cs)
    ]
    shown, missing = comparisons(rows)
    by = {b["paper"].group: b for b in shown if b["paper"].origin == "figure"}
    assert by["Human-Ego (Hard)"]["ours"]["mean"] == 0.5 and by["Human-Ego (Hard)"]["paper"].value == 82.9
    assert (
        by["Real Robot Deploy"]["ours"]["questions"] == 3 and by["Real Robot Deploy"]["paper"].value == 92.4
    )
    avg = by["Average"]
    assert avg["ours"]["mean"] == pytest.approx((1 + 0 + 1 + 0.5) / 4)  # 0.625, where pooling gives 3/7
    assert [g for g, _ in avg["ours"]["parts"]] == list(avg["paper"].average_of) and avg[
        "paper"
    ].value == 88.0
    assert {b["method"] for b in shown} == {"raven"}
    assert {(f.group, f.method) for f, _ in missing} >= {
        ("Average", "embedder-only"),
        ("Habitat Sim", "caption"),
    }
    assert all(f.benchmark == "raven-qa" for f, _ in missing)  # only the benchmarks run here are listed
    # a study's settings are rows of their own, as in the report's tables
    studied = comparisons(rows + [r | {"variant": "top_k=3"} for r in rows])[0]
    assert {b["method"] for b in studied} == {"raven", "raven [top_k=3]"}
    # without one of the groups there is no average of ours, and the report says what it needs
    shown, missing = comparisons([r for r in rows if r["question"]["subset"] != "irs_hard"])
    assert not any(b["paper"].group == "Average" for b in shown)
    (why,) = [w for f, w in missing if f.group == "Average" and f.method == "raven"]
    assert why == (
        "needs rows of ours for method raven in every group it averages "
        "(Habitat Sim, Real Robot Deploy, Human-Ego (Simple), Human-Ego (Hard))"
    )


def test_findingdory_long_subset_and_memory_efficiency(tmp_path: Path) -> None:
    # the loader records each question's episode as the release names it (its long-range subset
    # is episodes ep_91-ep_100)
    eps = load_dataset(f"findingdory:{write_findingdory_release(tmp_path / 'fd')}")
    assert {q.meta["ep_id"] for e in eps for q in e.questions} == {"ep_1"}
    rows = [
        _row("findingdory", "vlm-only", "ep_95:t0:0", True, meta={"ep_id": "ep_95"}),
        _row("findingdory", "vlm-only", "ep_1:t0:1", False, meta={"ep_id": "ep_1"}),
        _row("findingdory", "vlm-only", "ep_1:t1:2", False, meta={"ep_id": "ep_1"}),
    ]
    shown, missing = comparisons(rows)
    by = {b["paper"].group: b for b in shown}
    assert by["High-Level Success (Long)"]["ours"]["mean"] == 1.0  # ep_91-ep_100 only
    assert by["High-Level Success (Overall)"]["ours"]["mean"] == pytest.approx(1 / 3)
    assert by["Average Success Rate"]["ours"]["mean"] == pytest.approx((1 + 1 / 3) / 2)
    assert by["Average Success Rate"]["paper"].value == 33.2
    # memory efficiency: published, never put beside a value of ours
    assert not any(b["paper"].metric == "memory_efficiency" for b in shown)
    eff = [(f, w) for f, w in missing if f.metric == "memory_efficiency"]
    assert len(eff) == 6 and all(w.startswith("ravenmem does not compute this quantity") for _, w in eff)


def _lines(out: str) -> list[str]:
    """The console's 'beside the paper' lines, unwrapped."""
    said = " ".join(out.split())
    return [p.strip() for p in said.split("beside the paper: ")[1:]]


def _accuracy(rows: list[dict[str, Any]]) -> float:
    scored = [r["score"]["correct"] for r in rows if r["score"].get("correct") is not None]
    return float(np.mean(scored))


def _answers(run: Path) -> list[dict[str, Any]]:
    return [json.loads(x) for x in (run / "answers.jsonl").read_text().splitlines()]


def test_cli_report_puts_the_papers_figures_beside_ours(tmp_path: Path) -> None:
    data = write_raven_qa_release(tmp_path / "data")
    site = plugin_site(tmp_path)
    run = tmp_path / "run"
    with ScriptedModel(default=navqa_policy) as srv:
        r = rm(
            "eval",
            "--dataset",
            f"raven-qa:{data}",
            "--method",
            "raven,embedder-only",
            "--vlm",
            "scripted",
            "--vlm-base-url",
            srv.base_url,
            *EMB,
            "--out",
            str(run),
            site=site,
        )
    assert r.returncode == 0, r.stderr
    r = rm("eval", "report", str(run), "--out", str(tmp_path / "report.md"), site=site)
    assert r.returncode == 0, r.stderr
    lines = _lines(r.stdout + r.stderr)
    rows = [x for x in _answers(run) if x["method"] == "raven"]
    acc = {
        s: _accuracy([x for x in rows if x["question"]["subset"] == s]) for s in ("real_world", "irs_hard")
    }
    head = "raven-qa Real Robot Deploy (subset real_world) raven | test-color-eval | scripted: ours "
    (real,) = [x for x in lines if x.startswith(head)]
    assert real.startswith(f"{head}{100 * acc['real_world']:.1f} [")
    assert real.endswith(f"{THEIRS}: 92.4 % {UNNAMED}")
    (hard,) = [x for x in lines if x.startswith("raven-qa Human-Ego (Hard) (subset irs_hard) raven |")]
    assert f"ours {100 * acc['irs_hard']:.1f} [" in hard and hard.endswith(f"{THEIRS}: 82.9 % {UNNAMED}")
    (text,) = [
        x for x in lines if x.startswith("raven-qa real robot deployment tasks (subset real_world) raven")
    ]
    assert text.endswith(
        "the paper's (RAVEN authors' project page text): up to 92.4 % "
        "(model: not named in the text, encoder: not named in the text)"
    )
    (emb,) = [x for x in lines if x.startswith("raven-qa Human-Ego (Simple) (subset irs) embedder-only |")]
    assert emb.endswith(f"{THEIRS}: 90.7 % {UNNAMED}")
    # the average: the mean of the four subsets' accuracies, each over its own questions
    subsets = ("habitat_sim", "real_world", "irs", "irs_hard")
    mean = np.mean([_accuracy([x for x in rows if x["question"]["subset"] == s]) for s in subsets])
    (avg,) = [x for x in lines if x.startswith("raven-qa Average (all) raven |")]
    assert f"ours {100 * mean:.1f} (mean of Habitat Sim " in avg and avg.endswith(
        f"{THEIRS}: 88.0 % {UNNAMED}"
    )
    assert not any(
        x.startswith("raven-qa Habitat Sim (subset habitat_sim) caption") for x in lines
    )  # not run
    assert lines[-1].startswith("10 more published figure(s) for raven-qa have no value of ours beside them")
    report = (tmp_path / "report.md").read_text()
    section = report.split("## Beside the paper")[1].split("\n## ")[0]
    assert (
        "| raven-qa | Human-Ego (Hard) | subset irs_hard | raven | test-color-eval | scripted | "
        f"{100 * acc['irs_hard']:.1f} [" in section
    )
    assert (
        "| 82.9 % | RAVEN authors' project page figure: (a) RAVEN-QA, Human-Ego (Hard), bar Ours [2] | "
        "model: not named on the figure, encoder: not named on the figure |" in section
    )
    assert (
        "### Published, not run here" in section
        and "| raven-qa | Habitat Sim | subset habitat_sim | caption |" in section
    )
    assert (
        "[2] https://ravenmem.github.io/ (the RAVEN authors' project page, Benchmark Results: the bar chart "
        "static/images/raven_findingdory_navqa.jpg of repository ravenmem/ravenmem.github.io)" in section
    )
    assert "achieving up to 92.4% on real robot" in section and "| navqa |" not in section


def test_cli_report_navqa_per_type_figures(tmp_path: Path) -> None:
    repo = write_raven_navqa(tmp_path / "RAVEN")
    site = plugin_site(tmp_path)
    run = tmp_path / "run"
    with ScriptedModel(default=navqa_policy) as srv:
        args = ["--method", "raven", "--vlm", "scripted", "--vlm-base-url", srv.base_url]
        r = rm("eval", "--dataset", f"navqa:{repo}", *args, *EMB, "--out", str(run), site=site)
    assert r.returncode == 0, r.stderr
    r = rm("eval", "report", str(run), "--out", str(tmp_path / "report.md"), site=site)
    assert r.returncode == 0, r.stderr
    lines = _lines(r.stdout + r.stderr)
    rows = _answers(run)
    published = {"descriptive": 68.0, "positional": 78.9, "temporal": 87.2}
    values = [_accuracy(rows)]
    for kind, value in published.items():
        acc = _accuracy([x for x in rows if KINDS[x["question"]["type"]] == kind])
        values.append(acc)
        (line,) = [
            x for x in lines if x.startswith(f"navqa {kind.capitalize()} Accuracy (kind {kind}) raven |")
        ]
        assert f"ours {100 * acc:.1f} [" in line and line.endswith(f"{THEIRS}: {value:.1f} % {UNNAMED}")
    (overall,) = [x for x in lines if x.startswith("navqa Overall Accuracy (all) raven |")]
    assert f"ours {100 * values[0]:.1f} [" in overall and overall.endswith(f"{THEIRS}: 75.2 % {UNNAMED}")
    (avg,) = [x for x in lines if x.startswith("navqa Average (all) raven |")]
    assert f"ours {100 * np.mean(values):.1f} (mean of Overall Accuracy {100 * values[0]:.1f}, " in avg
    assert avg.endswith(f"{THEIRS}: 77.3 % {UNNAMED}")
    assert lines[-1].startswith("10 more published figure(s) for navqa")  # ReMEmbR and VLM Only, not run
