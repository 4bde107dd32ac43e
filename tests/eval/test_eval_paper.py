"""`ravenmem eval report` shows the RAVEN authors' published figure beside our row for the same
benchmark, questions and method, labelled as theirs with its source (issue 28)."""

from __future__ import annotations

from pathlib import Path

import pytest

from ravenmem.errors import InputError
from ravenmem.eval.paper import load_figures
from tests.agent.scripted_server import ScriptedModel
from tests.eval.eval_helpers import plugin_site, rm
from tests.eval.release_layouts import navqa_policy, write_raven_qa_release

EMB = ["--embedder", "test-color-eval", "--thumb-size", "32", "--workers", "1"]


def test_every_published_figure_names_its_source() -> None:
    figures = load_figures()
    assert figures and all(f.source.startswith("https://") and f.quote for f in figures)
    assert all(str(f.value).rstrip("0").rstrip(".") in f.quote for f in figures)  # the figure is in its quote
    with pytest.raises(InputError, match="paper_figures.json: unknown metric"):
        load_figures(
            '{"figures": [{"benchmark": "navqa", "method": "raven", "metric": "vibes", '
            '"value": 1, "source": "x"}]}'
        )
    with pytest.raises(InputError, match="not a list of published figures"):
        load_figures('{"figures": [{"benchmark": "navqa"}]}')


def test_cli_report_puts_the_papers_figure_beside_ours(tmp_path: Path) -> None:
    data = write_raven_qa_release(tmp_path / "data")
    site = plugin_site(tmp_path)
    run = tmp_path / "run"
    with ScriptedModel(default=navqa_policy) as srv:
        r = rm(
            "eval",
            "--dataset",
            f"raven-qa:{data}",
            "--episodes",
            "real_world/*",
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
    said = " ".join((r.stdout + r.stderr).split())
    assert (
        "beside the paper: raven-qa (subset real_world) raven | test-color-eval | scripted: ours " in said
        and "(n=2); the paper's (RAVEN authors): up to 92.4 % (model not named)" in said
    )
    assert "embedder-only |" not in said  # the paper publishes no figure for it here: none is shown
    report = (tmp_path / "report.md").read_text()
    section = report.split("## Beside the paper")[1].split("\n## ")[0]
    assert "| raven-qa | subset real_world | raven | test-color-eval | scripted |" in section
    assert "https://ravenmem.github.io/" in section and "achieving up to 92.4% on real robot" in section
