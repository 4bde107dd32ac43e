"""Reports, studies and the `ravenmem eval` command (in a subprocess, as users run it)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from ravenmem.agent.schema import Answer, Cost, Evidence
from ravenmem.errors import InputError
from ravenmem.eval.config import Thresholds, eval_keyframes
from ravenmem.eval.report import write_report
from ravenmem.eval.retrieval import embedder_study
from ravenmem.eval.runner import Runner, read_rows
from ravenmem.eval.studies import compression_study, coverage_cut, coverage_study, keyframe_spec, option_study
from ravenmem.ingest.keyframes import KeyframeConfig
from tests.cli.helpers import ForkedCli
from tests.eval.eval_helpers import (
    TARGETS,
    CountingColorEmbedder,
    no_vlm_env,
    plugin_site,
    rm,
    run_cfg,
    save,
    solid,
    write_findingdory,
    write_navqa,
)

PNG = b"\x89PNG\r\n\x1a\n"
QUIET = {"log": lambda _: None}


def line_of(text: str, start: str) -> str:
    return next(x for x in text.splitlines() if x.startswith(start))


def cells(line: str) -> list[str]:
    return [c.strip() for c in line.strip().strip("|").split("|")]


def test_random_cannot_pass_and_naming_the_frame_scores_everything(
    scoring_root: Path, tmp_path: Path
) -> None:
    cfg = run_cfg(f"raven-qa:{scoring_root}", ["embedder-only", "random"], tmp_path, seeds=3)
    s = Runner(cfg, embedder=CountingColorEmbedder(), **QUIET).run()
    g = {x["method"]: x for x in s["groups"]}
    right = g["embedder-only"]  # the colour embedder finds each named frame
    assert right["questions"] == 9 and right["accuracy"]["mean"] == 1.0 == right["frame_accuracy"]["mean"]
    assert right["position_accuracy"]["mean"] == 1.0 and right["pos_thresholds_m"] == [2.0]
    rnd = g["random"]  # one frame in 40, 3 m apart: right 1 time in 40 either way
    assert rnd["frame_accuracy"]["n"] == 27 and rnd["frame_accuracy"]["mean"] <= 0.15
    assert rnd["position_accuracy"]["mean"] <= 0.15
    sweep = dict(zip(rnd["pos_sweep"]["thresholds_m"], rnd["pos_sweep"]["accuracy"]))
    assert sweep[25.0]["mean"] > sweep[2.0]["mean"]  # the curve rises with the threshold
    by = right["by"]["subset_split"]
    assert set(by) == {"real_world/hard", "sim/hard", "sim/simple"}
    assert all(v["frame_accuracy"]["mean"] == 1.0 for v in by.values())

    text = write_report(tmp_path / "run", tmp_path / "rep" / "report.md").read_text()
    overall = line_of(text, "| embedder-only | test-color-eval | - | 9 | 3 |")
    assert overall.count("100.0 ± 0.0") >= 3  # accuracy, frame accuracy, position accuracy
    assert "| Frame acc. | Pos. acc. | Frame Qs |" in text and "within 2 m of an accepted position" in text
    assert "Frame Qs: accuracy over the questions of that type" in text  # not mistaken for Frame acc.
    assert "## Frame accuracy per subset and split (RAVEN-QA)" in text
    assert "| Method | Embedder | VLM | real_world/hard | sim/hard | sim/simple |" in text
    assert "## Position accuracy per subset and split (RAVEN-QA)" in text
    assert "## Position accuracy per category" in text and "information recall" in text
    assert (
        "## Accuracy per category" in text and "## Frame accuracy per category" not in text
    )  # the same here
    assert "## Position accuracy against the threshold" in text and "| ≤ 0.25 m |" in text
    assert "## Retrieval cost" in text and "α = memories shown" in text
    cost = line_of(text.split("## Retrieval cost")[1], "| embedder-only |")
    assert "| 0.025 ± 0.000 |" in cost  # one memory of 40 shown
    assert "frame times from timestamp_to_filename" in text  # how frames were placed in time
    figs = sorted(p.name for p in (tmp_path / "rep" / "report_figs").glob("*.png"))
    assert figs == [
        "accuracy_per_category.png",
        "accuracy_vs_retrieval_cost.png",
        "error_CDFs.png",
        "position_accuracy_vs_threshold.png",
    ]
    assert all((tmp_path / "rep" / "report_figs" / f).read_bytes()[:8] == PNG for f in figs)
    # a report may apply another threshold to the answers collected
    strict = write_report(tmp_path / "run", tmp_path / "strict.md", Thresholds(position_m=50.0)).read_text()
    assert "Position threshold(s): 50 m;" in strict and "Position threshold(s): 2 m;" in text
    assert line_of(strict, "| random |") != line_of(text, "| random |")


class Oracle:
    """Names the truth's frame for each question (what a perfect method answers), and counts cost."""

    def __init__(self, name: str, memory: Any, **opts: Any) -> None:
        self.name, self.memory, self.opts = name, memory, opts

    def ask(self, question: str, image: np.ndarray | None = None) -> Answer:
        colour = next(c for c in TARGETS if c in question)
        hit = self.memory.search_text(colour, k=1)[0].memory
        k = self.opts.get("top_k") or 5
        cost = Cost(memories_shown=k, memories_total=40, alpha=k / 40, images=k, prompt_tokens=100 * k)
        ev = Evidence(id=hit.id, t=hit.t, x=hit.pose.x, y=hit.pose.y)
        mode = self.opts.get("time_mode")
        position = list(hit.pose.xyz) if mode != "forward" else [999.0, 0.0, 0.0]
        return Answer(question=question, method=self.name, position=position, evidence=[ev], cost=cost)


def test_option_studies_table_curve_and_cost(scoring_root: Path, tmp_path: Path) -> None:
    seen: list[dict[str, Any]] = []

    def factory(name: str, memory: Any, **opts: Any) -> Oracle:
        seen.append(opts)
        return Oracle(name, memory, **opts)

    base = run_cfg(
        f"raven-qa:{scoring_root / 'sim' / 'simple'}",
        ["oracle"],
        tmp_path,
        method_opts={"preset": "raven-qa-human"},
    )
    doc = option_study(
        base,
        "top-k",
        [1, 5, 10],
        tmp_path / "topk",
        method_factory=factory,
        embedder=CountingColorEmbedder(),
        **QUIET,
    )
    assert {o["top_k"] for o in seen} == {1, 5, 10} and all(o["preset"] == "raven-qa-human" for o in seen)
    assert [p["value"] for p in doc["points"]] == [1, 5, 10]
    assert [p["alpha"]["mean"] for p in doc["points"]] == pytest.approx([1 / 40, 5 / 40, 10 / 40])
    assert sorted(p.name for p in (tmp_path / "topk").iterdir()) == [
        "study.json",
        "top_k-1",
        "top_k-10",
        "top_k-5",
    ]
    assert {r["variant"] for r in read_rows(tmp_path / "topk")} == {"top_k=1", "top_k=5", "top_k=10"}
    text = write_report(tmp_path / "topk", tmp_path / "topk" / "report.md").read_text()
    assert "## Top-k study" in text and "| top_k | Method | Accuracy |" in text
    assert line_of(text, "| 10 | oracle |").startswith(
        "| 10 | oracle | 100.0 [100.0, 100.0] | 100.0 [100.0, 100.0] | 100.0 [100.0, 100.0] | 0.250 ± 0.000 | 10.0"
    )
    figs = tmp_path / "topk" / "report_figs"
    assert (figs / "study_top-k_0.png").read_bytes()[:8] == PNG
    assert (figs / "accuracy_vs_retrieval_cost.png").stat().st_size > 5000
    # a categorical option: one point per value, in the order given; every value reaches the method
    doc = option_study(
        base,
        "time-mode",
        ["forward", "centred"],
        tmp_path / "tm",
        method_factory=factory,
        embedder=CountingColorEmbedder(),
        **QUIET,
    )
    pts = {p["value"]: p for p in doc["points"]}
    assert (
        pts["centred"]["position_accuracy"]["mean"] == 1.0
        and pts["forward"]["position_accuracy"]["mean"] == 0.0
    )
    assert pts["forward"]["frame_accuracy"]["mean"] == 1.0
    text = write_report(tmp_path / "tm", tmp_path / "tm" / "report.md").read_text()
    assert (
        "## Time-mode study" in text and (tmp_path / "tm" / "report_figs" / "study_time-mode_0.png").exists()
    )
    with pytest.raises(InputError, match="unknown study 'colour'"):
        option_study(base, "colour", [1], tmp_path / "x", method_factory=factory)
    with pytest.raises(InputError, match="--time-mode: one of forward, centred"):
        option_study(base, "time-mode", ["sideways"], tmp_path / "x", method_factory=factory)


def test_compression_study(scoring_root: Path, tmp_path: Path) -> None:
    emb = CountingColorEmbedder()
    base = run_cfg(f"raven-qa:{scoring_root / 'sim' / 'simple'}", ["embedder-only"], tmp_path)
    compression_study(base, [1], tmp_path / "first", embedder=emb, **QUIET)
    embedded = emb.images
    doc = compression_study(base, [1, 2, 5], tmp_path / "comp", embedder=emb, **QUIET)
    pts = {p["stride"]: p for p in doc["points"]}
    assert [(pts[s]["memories"], pts[s]["frames"]) for s in (1, 2, 5)] == [(40, 40), (20, 40), (8, 40)]
    assert pts[5]["sparsification"] == 5.0 and pts[1]["accuracy"]["mean"] == 1.0
    # red (frame 5) survives stride 5, blue (22) stride 2, green (13) neither: the named frame is gone
    assert pts[2]["frame_accuracy"]["mean"] == pytest.approx(1 / 3) == pts[5]["frame_accuracy"]["mean"]
    assert emb.images == embedded  # every stride reused the cached vectors
    rows = read_rows(tmp_path / "comp")
    assert {r["variant"] for r in rows} == {"stride=1", "stride=2", "stride=5"}
    text = write_report(tmp_path / "comp", tmp_path / "comp" / "report.md").read_text()
    assert "## Compression study" in text and "embedder-only [stride=5]" in text
    assert (tmp_path / "comp" / "report_figs" / "study_compression_0.png").read_bytes()[:8] == PNG


def test_coverage_study(scoring_root: Path, tmp_path: Path) -> None:
    from ravenmem.eval.datasets import load_dataset

    root = scoring_root / "sim" / "simple"
    (ep,) = load_dataset(f"raven-qa:{root}")
    assert (
        coverage_cut(ep, 0.5, 1.0) == 20
        and coverage_cut(ep, 1.0, 1.0) == 40
        and coverage_cut(ep, 0.5, 6.0) == 19
    )
    base = run_cfg(f"raven-qa:{root}", ["embedder-only"], tmp_path)
    doc = coverage_study(base, [0.5, 1.0], tmp_path / "cov", embedder=CountingColorEmbedder(), **QUIET)
    pts = {p["coverage"]: p for p in doc["points"]}
    assert pts[0.5]["memories"] == 20 and pts[1.0]["memories"] == 40
    # at half coverage the blue chair (frame 22) has not been seen yet
    assert pts[1.0]["accuracy"]["mean"] == 1.0 and pts[0.5]["accuracy"]["mean"] == pytest.approx(2 / 3)


def test_navqa_per_horizon_and_findingdory_relaxed_reports(tmp_path: Path) -> None:
    nav = write_navqa(tmp_path / "navqa")
    Runner(
        run_cfg(f"navqa:{nav}", ["embedder-only"], tmp_path, out="nav"),
        embedder=CountingColorEmbedder(),
        **QUIET,
    ).run()
    text = write_report(tmp_path / "nav", tmp_path / "nav.md").read_text()
    assert "## Per horizon: NaVQA's table" in text
    head = line_of(text, "| Method | Embedder | VLM | Horizon |")
    assert (
        "| Descriptive acc. | Pos. err (m) | Pos. acc. ≤ 15 m | Temporal err (min) | Temporal acc. ≤ 0.5 min |"
        in head
    )
    short = dict(zip(cells(head), cells(line_of(text, "| embedder-only | test-color-eval | - | short |"))))
    assert short["Pos. acc. ≤ 15 m"].startswith("100.0 [") and short["Pos. acc. ≤ 15 m"].endswith("(n=1)")
    assert short["Temporal acc. ≤ 0.5 min"].startswith("100.0") and short["Descriptive acc."] == "n/a"
    assert short["Pos. err (m)"] == "2.00 ± 0.00"  # the first blue frame, 2 m before the answer's
    long = dict(zip(cells(head), cells(line_of(text, "| embedder-only | test-color-eval | - | long |"))))
    # long: binary and text (not judged: not counted) are descriptive, duration temporal
    assert long["Pos. acc. ≤ 15 m"] == "n/a" and long["Descriptive acc."].endswith("(n=1)")
    assert long["Temporal acc. ≤ 0.5 min"] == "0.0 [0.0, 0.0] (n=1)"  # embedder-only gives no duration
    fd = write_findingdory(tmp_path / "fd")
    Runner(
        run_cfg(f"findingdory:{fd}", ["embedder-only"], tmp_path, out="fdrun"),
        embedder=CountingColorEmbedder(),
        **QUIET,
    ).run()
    text = write_report(tmp_path / "fdrun", tmp_path / "fd.md").read_text()
    assert "## Relaxed frame accuracy per category (FindingDory's relaxed score)" in text
    assert "frame i at in-game time 06:00 + i / 4.168 min" in text
    assert "multi-goal tasks" in line_of(text, "| Method | Embedder | VLM | multi-goal tasks")


def test_keyframes_default_to_every_frame() -> None:
    assert eval_keyframes(None) == KeyframeConfig.only() == eval_keyframes("all")  # every rule off
    assert eval_keyframes("stride=5") == KeyframeConfig.only(stride=5)
    assert eval_keyframes("fps=2,max_similarity=0.9") == KeyframeConfig.only(fps=2.0, max_similarity=0.9)
    cfg = KeyframeConfig.from_spec("stride=5,fps=2,max_similarity=0.9")
    assert KeyframeConfig.from_spec(keyframe_spec(cfg)) == cfg
    assert keyframe_spec(eval_keyframes(None)) == "all"


def test_top_k_option() -> None:
    from ravenmem.agent.presets import parse_top_k

    assert parse_top_k("7") == 7
    assert parse_top_k("time=200,text=30,position=1") == {"time": 200, "text": 30, "position": 1}
    with pytest.raises(InputError, match="--top-k"):
        parse_top_k("time=lots")


def test_eval_command_run_report_study_and_errors(
    scoring_root: Path, tmp_path: Path, forked_cli: ForkedCli
) -> None:
    """The real command, in a subprocess, with the colour embedder installed as a plugin (the
    refusals, each a one-line check, in forked processes of one driver: `ForkedCli`)."""
    site = plugin_site(tmp_path)
    common = [
        "--dataset",
        f"raven-qa:{scoring_root}",
        "--embedder",
        "test-color-eval",
        "--cache-dir",
        str(tmp_path / "cache"),
    ]
    run = tmp_path / "run"
    r = rm(
        "eval",
        *common,
        "--method",
        "embedder-only,random",
        "--seeds",
        "2",
        "--out",
        str(run),
        "--preset",
        "raven-qa-human",
        "--pos-threshold",
        "real_world=3",
        "--json",
        site=site,
    )
    assert r.returncode == 0, r.stderr
    summary = json.loads(r.stdout)
    g = {x["method"]: x for x in summary["groups"]}
    assert (
        g["embedder-only"]["frame_accuracy"]["mean"] == 1.0 and g["random"]["frame_accuracy"]["mean"] <= 0.2
    )
    rows = read_rows(run)
    assert len(rows) == 36 and {r["score"]["threshold_m"] for r in rows} == {2.0, 3.0}
    doc = json.loads((run / "config.json").read_text())
    assert doc["method_opts"] == {"preset": "raven-qa-human"} and doc["config"]["methods"]["names"] == [
        "embedder-only",
        "random",
    ]
    r = rm("eval", "report", str(run), "--out", str(tmp_path / "r.md"), site=site)
    assert r.returncode == 0, r.stderr
    text = (tmp_path / "r.md").read_text()
    assert text.startswith("# Evaluation report") and "Position threshold(s): 2 m, 3 m;" in text
    assert (tmp_path / "r_figs" / "accuracy_vs_retrieval_cost.png").read_bytes()[:8] == PNG
    # a study: its table is printed, its curve drawn by the report
    study = tmp_path / "tool-calls"
    r = rm(
        "eval",
        "study",
        "tool-calls",
        *common,
        "--method",
        "embedder-only",
        "--values",
        "0,3",
        "--out",
        str(study),
        "--episodes",
        "sim/*",
        site=site,
    )
    assert r.returncode == 0, r.stderr
    assert "tool-calls study" in r.stdout and "max_tool_calls" in r.stdout
    points = json.loads((study / "study.json").read_text())["points"]
    assert [(p["value"], p["frame_accuracy"]["mean"]) for p in points] == [(0, 1.0), (3, 1.0)]
    r = rm("eval", "report", str(study), "--out", str(study / "report.md"), site=site)
    assert r.returncode == 0 and (study / "report_figs" / "study_tool-calls_0.png").exists()
    # without a VLM, the methods that need one stop before any question: one line, exit 2
    r = forked_cli(
        "eval",
        *common,
        "--method",
        "offline,raven",
        "--out",
        str(tmp_path / "novlm"),
        paths=(site,),
        env=no_vlm_env(tmp_path),
    )
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert "--method raven needs a VLM and none is configured" in r.stderr
    assert not (tmp_path / "novlm" / "answers.jsonl").exists()
    r = rm("eval", "--help", env={"COLUMNS": "250"})
    for flag in (
        "--dataset",
        "--pos-threshold",
        "--scoring",
        "--caption-encoder",
        "--replay",
        "--time-mode",
        "--tz",
    ):
        assert flag in r.stdout, flag  # the typed config's options, on the command
    for args, msg in (
        (["--dataset", "nosuch:/x", "--method", "offline"], "unknown dataset 'nosuch'"),
        ([*common, "--method", "oracle"], "--method: unknown oracle"),
        (
            [*common, "--method", "offline", "--pos-threshold", "real_world=3,sim_world=1"],
            "--pos-threshold: no subset named sim_world in this dataset (its subsets: real_world, sim)",
        ),
        ([*common, "--method", "offline", "--scoring", "strict"], "--scoring: one of paper, release"),
        ([*common, "--method", "offline", "--time-mode", "sideways"], "--time-mode: one of forward, centred"),
    ):
        r = forked_cli("eval", *args, "--out", str(tmp_path / "bad"), paths=(site,))
        assert r.returncode == 2 and msg in r.stderr and "Traceback" not in r.stderr, (args, r.stderr)


def tiny_clip(folder: Path) -> Path:
    """A tiny random CLIP saved locally, as the hf embedder tests build it."""
    pytest.importorskip("transformers", reason="transformers not installed (extra 'hf')")
    from tests.embed.test_hf import TINY_TOWER, _clip_tokenizer, torch, transformers

    folder.mkdir(parents=True)
    tok, vocab_size = _clip_tokenizer(folder)
    text = {**TINY_TOWER, "vocab_size": vocab_size, "max_position_embeddings": 32}
    cfg = transformers.CLIPConfig(
        text_config=text | {"bos_token_id": 0, "eos_token_id": 1, "pad_token_id": 1},
        vision_config={**TINY_TOWER, "image_size": 32, "patch_size": 8},
        projection_dim=16,
    )
    torch.manual_seed(0)
    proc = transformers.CLIPProcessor(
        image_processor=transformers.CLIPImageProcessor(
            size={"shortest_edge": 32}, crop_size={"height": 32, "width": 32}
        ),
        tokenizer=tok,
    )
    transformers.CLIPModel(cfg).save_pretrained(folder / "clip")
    proc.save_pretrained(folder / "clip")
    return folder / "clip"


def write_labels(tmp: Path) -> tuple[Path, Path]:
    """15 labelled frames (objects = colours: 4 red, 4 green, 4 blue, 3 with nothing) and their labels file."""
    frames: dict[str, list[str]] = {}
    for i, colour in enumerate(["red", "green", "blue"] * 4 + ["grey"] * 3):
        save(tmp / "img" / f"f{i:02d}.jpg", solid(colour))
        frames[f"f{i:02d}.jpg"] = [colour] if colour != "grey" else []
    queries = {c: f"a {c} wall" for c in ("red", "green", "blue", "yellow")}
    (tmp / "labels.json").write_text(
        json.dumps({"queries": queries, "small_objects": ["blue"], "frames": frames})
    )
    return tmp / "labels.json", tmp / "img"


def test_embedder_study_two_embedders_side_by_side(tmp_path: Path) -> None:
    """The colour embedder and a tiny CLIP saved here, ranked on the same labelled frames."""
    labels, images = write_labels(tmp_path)
    clip = tiny_clip(tmp_path / "models")
    doc = embedder_study(
        labels, images, ["colour", f"hf:{clip}"], instances={"colour": CountingColorEmbedder()}
    )
    assert doc["objects"] == ["red", "green", "blue"] and doc["frames"] == 15  # yellow is in no frame
    pts = {(p["embedder"], p["direction"]): p for p in doc["points"]}
    assert pts[("colour", "text->image")]["mAP"] == 1.0 == pts[("colour", "image->image")]["mAP"]
    assert pts[("colour", "text->image")]["P@k"] == pytest.approx(0.8)  # 4 positives in the top 5
    assert pts[("colour", "image->image")]["P@k"] == pytest.approx(0.6)  # 3 other views in the top 5
    tiny = pts[(f"hf:{clip}", "text->image")]
    assert (
        tiny["name"] == f"hf:{clip.resolve()}" and 0.0 < tiny["mAP"] < 1.0
    )  # random weights: no better than chance
    assert pts[(f"hf:{clip}", "image->image")]["mAP"] == 1.0  # identical frames look identical to any model
    assert doc["chance"]["text->image"] == pytest.approx(4 / 15)
    assert doc["chance"]["image->image"] == pytest.approx(3 / 14)


def test_embedder_study_command(tmp_path: Path) -> None:
    labels, images = write_labels(tmp_path)
    out, site = tmp_path / "emb", plugin_site(tmp_path)
    r = rm(
        "eval",
        "study",
        "embedders",
        "--labels",
        str(labels),
        "--images",
        str(images),
        "--embedders",
        "test-color-eval",
        "--k",
        "4",
        "--out",
        str(out),
        site=site,
    )
    assert r.returncode == 0, r.stderr
    assert "random ranking" in r.stdout and "test-color-eval" in r.stdout and "P@4" in r.stdout
    assert json.loads((out / "study.json").read_text())["points"][0]["P@k"] == 1.0
    r = rm("eval", "report", str(out), "--out", str(out / "report.md"))
    assert r.returncode == 0, r.stderr
    assert "## Embedders study" in (out / "report.md").read_text()
    assert (out / "report_figs" / "study_embedders_0.png").read_bytes()[:8] == PNG
    r = rm("eval", "study", "embedders", "--labels", str(labels), "--images", str(tmp_path), site=site)
    assert r.returncode == 2 and "labelled frame(s) not found" in r.stderr
    r = rm("eval", "study", "embedders", "--labels", str(images / "f00.jpg"), "--images", str(images))
    assert r.returncode == 2 and "cannot read the labels JSON" in r.stderr


def test_eval_sends_pictures_at_the_size_asked_for(scoring_root: Path, tmp_path: Path) -> None:
    """The stored size (--thumb-size) and the size sent to the model (--image-max-side) are
    separate settings of `ravenmem eval` too; the sent size is part of the run's identity."""
    import base64
    import io

    from PIL import Image

    from tests.agent.scripted_server import ScriptedModel
    from tests.eval.test_eval_llm import vlm_reply

    site = plugin_site(tmp_path)
    common = ["--dataset", f"raven-qa:{scoring_root / 'sim' / 'simple'}", "--embedder", "test-color-eval"]
    common += ["--cache-dir", str(tmp_path / "cache"), "--method", "raven", "--vlm", "scripted"]
    with ScriptedModel(default=vlm_reply) as srv:
        r = rm(
            "eval",
            *common,
            "--vlm-base-url",
            srv.base_url,
            "--image-max-side",
            "16",
            "--out",
            str(tmp_path / "r"),
            site=site,
        )
        assert r.returncode == 0, r.stderr
        sizes = {
            Image.open(io.BytesIO(base64.b64decode(p["image_url"]["url"].split(",", 1)[1]))).size
            for body in srv.requests
            for m in body["messages"]
            if isinstance(m.get("content"), list)
            for p in m["content"]
            if p.get("type") == "image_url"
        }
    assert sizes == {(16, 12)}  # the stored 32x24 frames, shrunk to 16 px on the longer side
    assert json.loads((tmp_path / "r" / "config.json").read_text())["method_opts"]["image_max_side"] == 16
    bad = rm("eval", *common, "--image-max-side", "4", "--out", str(tmp_path / "bad"), site=site)
    assert bad.returncode == 2 and bad.stderr.strip() == "error: --image-max-side must be >= 16 px, got 4"
