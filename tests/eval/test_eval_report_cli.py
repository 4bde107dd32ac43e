from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest
from typer.testing import CliRunner

from ravenmem.embed.base import EMBEDDERS
from ravenmem.eval.report import write_report
from ravenmem.eval.runner import RunConfig, Runner, read_rows
from ravenmem.eval.studies import compression_study, coverage_cut, coverage_study, keyframe_spec
from ravenmem.ingest.keyframes import parse_keyframes
from tests.eval.eval_helpers import CountingColorEmbedder, write_raven_video

PNG = b"\x89PNG\r\n\x1a\n"


def base(root: Path, tmp: Path, **kw: Any) -> RunConfig:
    return RunConfig(**({"dataset": f"raven-qa:{root}", "methods": ["embedder-only", "random"], "out": str(tmp / "run"),
                         "cache_dir": str(tmp / "cache"), "progress": False, "thumb_size": 32} | kw))  # fmt: skip


def test_report_tables_and_plots(raven_root: Path, tmp_path: Path) -> None:
    Runner(base(raven_root, tmp_path, seeds=2), embedder=CountingColorEmbedder(), log=lambda _: None).run()
    md = write_report(tmp_path / "run", tmp_path / "rep" / "report.md")
    text = md.read_text()
    assert "## Overall" in text and "## Accuracy per category" in text and "## Accuracy per horizon" in text
    line = next(x for x in text.splitlines() if x.startswith("| embedder-only | test-color-eval | - |"))
    assert "| 100.0 ± 0.0 |" in line  # 2 seeds: mean ± std
    assert "information recall" in text and "dominant" in text
    figs = sorted((tmp_path / "rep" / "report_figs").glob("*.png"))
    assert [f.name for f in figs] == ["accuracy_per_category.png", "accuracy_vs_alpha.png", "error_CDFs.png"]
    assert all(f.read_bytes()[:8] == PNG and f.stat().st_size > 5000 for f in figs)
    assert "![accuracy per category](report_figs/accuracy_per_category.png)" in text
    # stricter threshold at report time re-scores the collected answers
    from ravenmem.eval.metrics import Thresholds

    strict = write_report(tmp_path / "run", tmp_path / "strict.md", Thresholds(position_m=0.01)).read_text()
    assert "Position threshold(s): 0.01 m;" in strict and "Position threshold(s): 2 m;" in text
    rnd = [next(x for x in t.splitlines() if x.startswith("| random |")) for t in (text, strict)]
    assert rnd[0] != rnd[1]  # random answers land within 2 m more often than exactly on the spot


def test_compression_study(raven_root: Path, tmp_path: Path) -> None:
    emb = CountingColorEmbedder()
    doc = compression_study(base(raven_root, tmp_path, methods=["embedder-only"]), [1, 2, 5], tmp_path / "comp",
                            embedder=emb, log=lambda _: None)  # fmt: skip
    pts = {p["stride"]: p for p in doc["points"]}
    assert [(pts[s]["memories"], pts[s]["frames"]) for s in (1, 2, 5)] == [(10, 10), (5, 10), (2, 10)]
    assert pts[5]["sparsification"] == 5.0 and pts[1]["accuracy"]["mean"] == 1.0
    assert emb.images == 10  # every stride reused the cached vectors
    assert json.loads((tmp_path / "comp" / "study.json").read_text())["study"] == "compression"
    rows = read_rows(tmp_path / "comp")
    assert {r["variant"] for r in rows} == {"stride=1", "stride=2", "stride=5"}
    text = write_report(tmp_path / "comp", tmp_path / "comp" / "report.md").read_text()
    assert "## Compression study" in text and "embedder-only [stride=5]" in text
    assert (tmp_path / "comp" / "report_figs" / "study_compression_0.png").read_bytes()[:8] == PNG


def test_coverage_study(tmp_path: Path) -> None:
    root = tmp_path / "sim"
    write_raven_video(root / "ep0")
    from ravenmem.eval.datasets import load_dataset

    (ep,) = load_dataset(f"raven-qa:{root}")
    assert (
        coverage_cut(ep, 0.5, 1.0) == 5
        and coverage_cut(ep, 1.0, 1.0) == 10
        and coverage_cut(ep, 0.5, 4.0) == 5
    )
    doc = coverage_study(base(root, tmp_path, methods=["embedder-only"]), [0.5, 1.0], tmp_path / "cov",
                         embedder=CountingColorEmbedder(), log=lambda _: None)  # fmt: skip
    pts = {p["coverage"]: p for p in doc["points"]}
    assert pts[0.5]["memories"] == 5 and pts[1.0]["memories"] == 10
    # at half coverage the yellow place (x = 6..7) has not been seen yet
    assert pts[1.0]["accuracy"]["mean"] == 1.0 and pts[0.5]["accuracy"]["mean"] == 0.75


def test_keyframe_spec_round_trip() -> None:
    cfg = parse_keyframes("stride=5,fps=2,max_similarity=0.9")
    assert parse_keyframes(keyframe_spec(cfg)) == cfg
    assert keyframe_spec(parse_keyframes(None)) == "all"


@pytest.fixture
def cli_embedder() -> Any:
    EMBEDDERS.register("test-color-eval")(lambda spec, **kw: CountingColorEmbedder())
    yield "test-color-eval"
    EMBEDDERS._factories.pop("test-color-eval", None)


def test_cli_run_report_and_errors(raven_root: Path, tmp_path: Path, cli_embedder: str) -> None:
    from ravenmem.cli.main import app

    runner = CliRunner()
    args = ["eval", "--dataset", f"raven-qa:{raven_root}", "--method", "embedder-only,random", "--embedder", cli_embedder,
            "--out", str(tmp_path / "run"), "--cache-dir", str(tmp_path / "cache"), "--seeds", "2",
            "--pos-threshold", "real_world=3", "--json"]  # fmt: skip
    res = runner.invoke(app, args)
    assert res.exit_code == 0, res.output
    summary = json.loads(res.stdout[res.stdout.index("{") :])
    assert {g["method"] for g in summary["groups"]} == {"embedder-only", "random"}
    rows = read_rows(tmp_path / "run")
    assert len(rows) == 16 and rows[0]["pos_threshold"] == 3.0
    res = runner.invoke(app, ["eval", "report", str(tmp_path / "run"), "--out", str(tmp_path / "r.md")])
    assert res.exit_code == 0, res.output
    assert (tmp_path / "r.md").read_text().startswith("# Evaluation report")
    res = runner.invoke(app, ["eval", "--dataset", "nosuch:/x", "--method", "offline"])
    assert res.exit_code != 0 and "unknown dataset 'nosuch'" in str(res.exception)
    res = runner.invoke(app, ["eval", "--dataset", f"raven-qa:{raven_root}", "--method", "oracle"])
    assert "unknown oracle" in str(res.exception)
    res = runner.invoke(app, ["eval", "--dataset", f"navqa:{raven_root}", "--method", "offline",
                              "--pos-threshold", "a=1"])  # fmt: skip
    assert "is for raven-qa datasets" in str(res.exception)


def test_top_k_option() -> None:
    from ravenmem.cli.eval import parse_top_k
    from ravenmem.errors import InputError
    from ravenmem.eval.runner import per_tool_top_k_supported

    assert parse_top_k("7") == 7
    assert parse_top_k("time=200,text=30,position=1") == {"time": 200, "text": 30, "position": 1}
    with pytest.raises(InputError, match="--top-k"):
        parse_top_k("time=lots")
    cfg = RunConfig(dataset="raven-qa:x", methods=["raven"], method_opts={"top_k": {"time": 200}})
    if per_tool_top_k_supported():
        cfg.validate()
    else:
        with pytest.raises(InputError, match="per tool"):
            cfg.validate()


def test_cli_studies(raven_root: Path, tmp_path: Path, cli_embedder: str) -> None:
    from ravenmem.cli.main import app

    common = ["--dataset", f"raven-qa:{raven_root}", "--method", "embedder-only", "--embedder", cli_embedder,
              "--cache-dir", str(tmp_path / "cache")]  # fmt: skip
    res = CliRunner().invoke(
        app, ["eval", "study", "compression", "--strides", "1,5", "--out", str(tmp_path / "c"), *common]
    )
    assert res.exit_code == 0, res.output
    assert [p["memories"] for p in json.loads((tmp_path / "c" / "study.json").read_text())["points"]] == [
        10,
        2,
    ]
    res = CliRunner().invoke(
        app, ["eval", "study", "coverage", "--fractions", "0.5,1", "--out", str(tmp_path / "v"), *common]
    )
    assert res.exit_code == 0, res.output
    assert [p["memories"] for p in json.loads((tmp_path / "v" / "study.json").read_text())["points"]] == [
        5,
        10,
    ]
