"""`ravenmem eval`: run benchmarks, write reports, run the studies.

ravenmem eval --dataset raven-qa:/data/RAVEN_QA/real_world --method raven --vlm gemini-2.5-flash --seeds 3
ravenmem eval --dataset tum:../shared/data/tum_fr1_rpy --queries benchmarks/data/tum_queries.json --method offline
ravenmem eval report runs/2026-11-21/ --out report.md
ravenmem eval study compression --dataset ... --method offline --strides 1,5,25,250 --out runs/compression
ravenmem eval study top-k --dataset ... --method raven --vlm ... --values 1,3,5,10 --out runs/topk
ravenmem eval study embedders --labels benchmarks/data/tum_labels.json --images DIR/rgb --embedders offline,hf:PATH
ravenmem eval judge runs/2026-11-21/navqa_raven --judge gpt-4o-mini

Every command that runs questions takes the same run options (`RUN_OPTIONS`, declared once and
added to each command by `run_options`), and `build_run_config` turns them into the typed
`RunConfig` in one place.
"""

from __future__ import annotations

import functools
import inspect
import json
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Annotated, Any, TypeVar

import typer
from rich.console import Console
from rich.table import Table

from ..agent.presets import parse_top_k
from ..errors import InputError
from ._console import esc, out_console

eval_app = typer.Typer(
    help="Benchmarks (RAVEN-QA, NaVQA, FindingDory, your own questions), reports and studies.",
    no_args_is_help=False,
)
study_app = typer.Typer(
    help="Accuracy as one setting changes: keyframe rate, coverage, top-k, scores shown, time mode, "
    "tool-call budget; and retrieval quality per embedder.",
    no_args_is_help=True,
)
eval_app.add_typer(study_app, name="study")
console = Console(stderr=True)

F = TypeVar("F", bound=Callable[..., Any])


def _opt(*names: str, help: str) -> Any:
    return typer.Option(*names, help=help)


# name, type, default, typer option: the options of every command that runs questions
RUN_OPTIONS: list[tuple[str, Any, Any, Any]] = [
    (
        "dataset",
        str | None,
        None,
        _opt(
            "--dataset",
            "-d",
            help="NAME:PATH, NAME = raven-qa | navqa | findingdory | tum | video | folder | rosbag | memory | queries",
        ),
    ),
    (
        "method",
        str | None,
        None,
        _opt("--method", help="comma-separated: raven, offline, embedder-only, vlm-only, caption, random"),
    ),
    (
        "queries",
        Path | None,
        None,
        _opt("--queries", help="our questions.json for tum:/video:/folder:/rosbag:/memory: datasets"),
    ),
    ("embedder", str, "offline", _opt("--embedder", help="offline | open_clip:MODEL/TAG | hf:NAME_OR_PATH")),
    (
        "vlm",
        str | None,
        None,
        _opt("--vlm", help="VLM model name (endpoint from --vlm-base-url / RAVENMEM_VLM_BASE_URL)"),
    ),
    ("vlm_base_url", str | None, None, _opt("--vlm-base-url", help="OpenAI-compatible endpoint for the VLM")),
    ("seeds", int, 1, _opt("--seeds", help="repeat every question with seeds 0..N-1 (mean ± std)")),
    (
        "cache_dir",
        Path,
        Path(".ravenmem-cache/eval"),
        _opt("--cache-dir", help="where memories and embeddings are cached"),
    ),
    ("workers", int, 4, _opt("--workers", help="questions answered in parallel")),
    (
        "keyframes",
        str | None,
        None,
        _opt("--keyframes", help="e.g. 'stride=5,fps=2,max_similarity=0.95' (default: all frames)"),
    ),
    (
        "ocr",
        bool,
        False,
        _opt("--ocr/--no-ocr", help="read text in keyframes while building memories (slower)"),
    ),
    ("thumb_size", int, 320, _opt("--thumb-size", help="thumbnail longer side (px) in built memories")),
    (
        "image_max_side",
        int | None,
        None,
        _opt("--image-max-side", help="longest side in px of images sent to the model (default: as stored)"),
    ),
    (
        "top_k",
        str | None,
        None,
        _opt("--top-k", help="memories per tool call: N, or per tool 'time=200,text=30,position=1'"),
    ),
    (
        "max_tool_calls",
        int | None,
        None,
        _opt("--max-tool-calls", help="tool calls before the model must answer"),
    ),
    ("frames", int | None, None, _opt("--frames", help="vlm-only: frames sampled over the history")),
    (
        "preset",
        str | None,
        None,
        _opt("--preset", help="the paper's settings per dataset: raven-qa | navqa | findingdory"),
    ),
    ("temperature", float | None, None, _opt("--temperature", help="the VLM's sampling temperature")),
    (
        "show_scores",
        bool | None,
        None,
        _opt("--show-scores/--hide-scores", help="similarity scores shown to the model"),
    ),
    (
        "time_mode",
        str | None,
        None,
        _opt("--time-mode", help="time tool: forward (from the time on) | centred (around it)"),
    ),
    (
        "pos_threshold",
        str | None,
        None,
        _opt("--pos-threshold", help="metres: one number, or per RAVEN-QA subset 'real_world=3,sim=1'"),
    ),
    ("time_threshold", float | None, None, _opt("--time-threshold", help="minutes (default 0.5)")),
    ("duration_threshold", float | None, None, _opt("--duration-threshold", help="minutes (default 0.5)")),
    (
        "frame_tolerance",
        float | None,
        None,
        _opt("--frame-tolerance", help="seconds either side of an accepted frame"),
    ),
    ("planar", bool, False, _opt("--planar", help="position error in x, y only")),
    ("judge", str | None, None, _opt("--judge", help="LLM judge model for text answers")),
    (
        "judge_base_url",
        str | None,
        None,
        _opt("--judge-base-url", help="endpoint of the judge (default: the VLM's)"),
    ),
    (
        "rate",
        float | None,
        None,
        _opt("--rate", help="raven-qa: frames per second where no timestamps are given"),
    ),
    ("tz", str | None, None, _opt("--tz", help="navqa: time zone of data.csv timestamps (America/Chicago)")),
    ("split", str | None, None, _opt("--split", help="findingdory: split name (validation)")),
    ("limit", int | None, None, _opt("--limit", help="only the first N questions (smoke runs)")),
    ("episodes", str | None, None, _opt("--episodes", help="only episodes whose id matches this glob")),
    (
        "retry_failed",
        bool,
        False,
        _opt("--retry-failed", help="answer again the questions whose method failed"),
    ),
]


def run_options(fn: F) -> F:
    """Give a command the run options: its own parameters stay, the run options are added, and
    the command receives them as one `cfg: RunConfig` (built by `build_run_config`)."""
    own = [p for p in inspect.signature(fn, eval_str=True).parameters.values() if p.name != "cfg"]
    shared = [
        inspect.Parameter(
            name, inspect.Parameter.KEYWORD_ONLY, default=default, annotation=Annotated[typ, option]
        )
        for name, typ, default, option in RUN_OPTIONS
    ]
    names = [name for name, *_ in RUN_OPTIONS]

    @functools.wraps(fn)
    def wrapper(**kw: Any) -> Any:
        if getattr(kw.get("ctx"), "invoked_subcommand", None) is not None:
            return None  # `eval report ...`: the group's callback has nothing to run
        run = {n: kw.pop(n) for n in names}
        return fn(cfg=build_run_config(**run), **kw)

    params = [p.replace(kind=inspect.Parameter.KEYWORD_ONLY) for p in own] + shared
    wrapper.__signature__ = inspect.Signature(params)  # type: ignore[attr-defined]
    wrapper.__annotations__ = {p.name: p.annotation for p in params}
    return wrapper  # type: ignore[return-value]


def _split_list(text: str | None, what: str) -> list[str]:
    items = [x.strip() for x in (text or "").split(",") if x.strip()]
    if not items:
        raise InputError(f"{what}: give at least one value")
    return items


def _ints(text: str, what: str) -> list[int]:
    try:
        return [int(x) for x in _split_list(text, what)]
    except ValueError:
        raise InputError(f"{what}: expected comma-separated whole numbers, got {text!r}") from None


def _floats(text: str, what: str) -> list[float]:
    try:
        return [float(x) for x in _split_list(text, what)]
    except ValueError:
        raise InputError(f"{what}: expected comma-separated numbers, got {text!r}") from None


def _pos_threshold(text: str | None) -> tuple[float | None, dict[str, float] | None]:
    """'2.5' -> (2.5, None); 'real_world=3,sim=1' -> (None, {'real_world': 3.0, 'sim': 1.0})."""
    if not text:
        return None, None
    if "=" not in text:
        return _floats(text, "--pos-threshold")[0], None
    per = {}
    for part in _split_list(text, "--pos-threshold"):
        k, _, v = part.partition("=")
        per[k.strip()] = _floats(v, "--pos-threshold")[0]
    return None, per


def build_run_config(**o: Any) -> Any:
    """The RunConfig from the run options' values: the one place CLI values become a config."""
    from ..eval.config import DatasetConfig, MemoryConfig, MethodConfig, ModelConfig, RunConfig, Thresholds

    if not o["dataset"]:
        raise InputError("--dataset NAME:PATH is required (e.g. raven-qa:/data/RAVEN_QA/real_world)")
    pos_m, pos_per = _pos_threshold(o["pos_threshold"])
    minutes = {k: o[k] * 60.0 for k in ("time_threshold", "duration_threshold") if o[k] is not None}
    thresholds = Thresholds(
        position_m=pos_m,
        time_s=minutes.get("time_threshold", 30.0),
        duration_s=minutes.get("duration_threshold", 30.0),
        frame_s=o["frame_tolerance"],
        planar=o["planar"],
    )
    return RunConfig(
        dataset=DatasetConfig(
            spec=o["dataset"],
            queries=str(o["queries"]) if o["queries"] else None,
            rate=o["rate"],
            tz=o["tz"],
            split=o["split"],
            pos_threshold=pos_per,
            episodes=o["episodes"],
            limit=o["limit"],
        ),
        methods=MethodConfig(
            names=_split_list(o["method"], "--method"),
            top_k=parse_top_k(o["top_k"]),
            max_tool_calls=o["max_tool_calls"],
            frames=o["frames"],
            show_scores=o["show_scores"],
            time_mode=o["time_mode"],
            preset=o["preset"],
            temperature=o["temperature"],
            image_max_side=o["image_max_side"],
        ),
        models=ModelConfig(
            embedder=o["embedder"],
            vlm=o["vlm"],
            vlm_base_url=o["vlm_base_url"],
            judge=o["judge"],
            judge_base_url=o["judge_base_url"],
        ),
        memory=MemoryConfig(
            keyframes=o["keyframes"], ocr=o["ocr"], thumb_size=o["thumb_size"], cache_dir=str(o["cache_dir"])
        ),
        thresholds=thresholds,
        seeds=o["seeds"],
        workers=o["workers"],
        retry_failed=o["retry_failed"],
    )


def _log(msg: str) -> None:
    console.print(esc(msg), highlight=False)


def _print_summary(summary: dict[str, Any], json_out: bool) -> None:
    if json_out:
        sys.stdout.write(json.dumps(summary, indent=2, default=str) + "\n")
        return
    from ..eval.report import _num, _pct

    table = Table(title=esc(f"{summary['rows']} answers in {summary.get('run_dir', '')}"))
    cols = [
        "method",
        "embedder",
        "VLM",
        "Q",
        "accuracy %",
        "frame %",
        "position %",
        "pos err m",
        "time err min",
    ]
    for col in cols + ["alpha", "images/q", "tokens/q", "s/q"]:
        table.add_column(col)
    for g in summary["groups"]:
        table.add_row(
            esc(g["method"] + (f" [{g['variant']}]" if g.get("variant") else "")),
            esc(g["embedder"]),
            esc(g["vlm"]),
            str(g["questions"]),
            _pct(g["accuracy"]),
            _pct(g.get("frame_accuracy")),
            _pct(g.get("position_accuracy")),
            _num(g["pos_error_m"]),
            _num(g["time_error_min"]),
            _num(g["alpha"], 3),
            _num(g["images_per_q"], 1),
            _num(g["tokens_per_q"], 0),
            _num(g["seconds_per_q"], 2),
        )
    out_console().print(table)
    for g in summary["groups"]:
        if g["not_judged"]:
            console.print(
                f"{esc(g['method'])}: {g['not_judged']} text answer(s) not scored (no LLM judge; use --judge MODEL)"
            )


@eval_app.callback(invoke_without_command=True)
@run_options
def eval_main(
    ctx: typer.Context,
    cfg: Any = None,
    out: Annotated[
        Path | None, typer.Option("--out", "-o", help="run folder (default runs/<date>/<name>)")
    ] = None,
    name: Annotated[str | None, typer.Option("--name", help="run name under runs/<date>/")] = None,
    runs_dir: Annotated[Path, typer.Option("--runs-dir", help="parent of dated run folders")] = Path("runs"),
    json_out: Annotated[bool, typer.Option("--json", help="print the summary as JSON")] = False,
) -> None:
    """Evaluate methods on a benchmark: one JSONL row per answer in the run folder, then a summary."""
    from ..eval.config import OutputConfig
    from ..eval.runner import Runner

    cfg.output = OutputConfig(out=str(out) if out else None, runs_dir=str(runs_dir), name=name)
    summary = Runner(cfg, log=_log).run()
    _print_summary(summary, json_out)
    if not json_out:
        run_dir = summary["run_dir"]
        console.print(
            esc(
                f"rows: {Path(run_dir) / 'answers.jsonl'}; report: ravenmem eval report {run_dir} --out report.md"
            )
        )


@eval_app.command("report")
def report_cmd(
    run_dir: Annotated[
        Path, typer.Argument(help="a run folder, or a folder of runs (e.g. runs/2026-11-21/)")
    ],
    out: Annotated[
        Path, typer.Option("--out", "-o", help="markdown file; PNGs go to <stem>_figs/ beside it")
    ] = Path("report.md"),
    pos_threshold: Annotated[
        float | None, typer.Option("--pos-threshold", help="re-score with this position threshold (m)")
    ] = None,
    time_threshold: Annotated[
        float | None, typer.Option("--time-threshold", help="re-score with this time threshold (min)")
    ] = None,
) -> None:
    """Markdown tables (method x embedder x VLM, per category, split, horizon, cost) and PNG plots."""
    from dataclasses import replace

    from ..eval.report import write_report
    from ..eval.runner import run_thresholds

    thr = run_thresholds(run_dir)
    if pos_threshold is not None:
        thr = replace(thr, position_m=pos_threshold)
    if time_threshold is not None:
        thr = replace(thr, time_s=60.0 * time_threshold)
    path = write_report(run_dir, out, thresholds=thr)
    console.print(esc(f"wrote {path} (figures in {path.parent / (path.stem + '_figs')})"))


@eval_app.command("judge")
def judge_cmd(
    run_dir: Annotated[Path, typer.Argument(help="one run folder")],
    judge: Annotated[str, typer.Option("--judge", help="judge model")],
    judge_base_url: Annotated[
        str | None, typer.Option("--judge-base-url", help="OpenAI-compatible endpoint")
    ] = None,
) -> None:
    """Judge the text answers of a finished run that were not judged yet."""
    from ..agent.config import VLMConfig
    from ..eval.judge import Judge
    from ..eval.runner import rejudge

    n = rejudge(run_dir, Judge(VLMConfig.resolve(model=judge, base_url=judge_base_url)))
    console.print(esc(f"judged {n} text answer(s) in {run_dir}"))


# ------------------------------------------------------------------------------------ studies
StudyOut = Annotated[
    Path, typer.Option("--out", "-o", help="study folder (a run folder per setting + study.json)")
]


def _print_study(doc: dict[str, Any], out: Path) -> None:
    from ..eval.report import _num, _pct

    first = {"compression": "stride", "coverage": "coverage", "consolidation": "strategy / budget"}.get(
        doc["study"], doc.get("option", "value")
    )
    table = Table(title=f"{doc['study']} study")
    for col in (
        first,
        "memories",
        "method",
        "accuracy %",
        "frame %",
        "position %",
        "alpha",
        "images/q",
        "tokens/q",
        "tool calls/q",
    ):
        table.add_column(col)
    for p in doc["points"]:
        value = f"{100 * p['coverage']:.0f}%" if "coverage" in p else str(p.get("stride", p.get("value")))
        if doc["study"] == "consolidation":
            value = p["strategy"] + ("" if p.get("budget") is None else f" {p['budget']}")
        table.add_row(
            esc(value),
            str(p.get("memories", "")),
            esc(p["method"]),
            _pct(p["accuracy"]),
            _pct(p.get("frame_accuracy")),
            _pct(p.get("position_accuracy")),
            _num(p["alpha"], 3),
            _num(p["images_per_q"], 1),
            _num(p["tokens_per_q"], 0),
            _num(p["tool_calls_per_q"], 1),
        )
    out_console().print(table)
    console.print(
        esc(f"wrote {out / 'study.json'}; curve: ravenmem eval report {out} --out {out / 'report.md'}")
    )


@study_app.command("compression")
@run_options
def compression_cmd(
    out: StudyOut,
    cfg: Any = None,
    strides: Annotated[str, typer.Option("--strides", help="keyframe strides")] = "1,2,5,10,25,50,100,250",
) -> None:
    """Accuracy vs keyframe stride (frames per memory), the sparsification curve."""
    from ..eval.studies import compression_study

    doc = compression_study(cfg, _ints(strides, "--strides"), out, log=_log)
    _print_study(doc, out)


@study_app.command("coverage")
@run_options
def coverage_cmd(
    out: StudyOut,
    cfg: Any = None,
    fractions: Annotated[
        str, typer.Option("--fractions", help="coverage fractions in (0, 1]")
    ] = "0.25,0.5,0.75,1.0",
    cell: Annotated[float, typer.Option("--cell", help="grid cell (m) for coverage")] = 1.0,
) -> None:
    """Accuracy vs the fraction of the environment explored when the questions are asked."""
    from ..eval.studies import coverage_study

    doc = coverage_study(cfg, _floats(fractions, "--fractions"), out, cell=cell, log=_log)
    _print_study(doc, out)


@study_app.command("consolidation")
@run_options
def consolidation_cmd(
    out: StudyOut,
    cfg: Any = None,
    budgets: Annotated[str, typer.Option("--budgets", help="memories kept per episode")] = "200,100,50,25,12",
    strategies: Annotated[
        str, typer.Option("--strategies", help="consolidate (merge near-duplicates), uniform (thin in time)")
    ] = "consolidate,uniform",
    max_distance: Annotated[
        float, typer.Option("--max-distance", help="consolidate: a merged run fits in this many metres")
    ] = 1.0,
) -> None:
    """Accuracy vs memories kept: each memory consolidated to a budget, beside it thinned
    uniformly in time to the same budget, and the full memory."""
    from ..eval.studies import consolidation_study

    doc = consolidation_study(
        cfg,
        _ints(budgets, "--budgets"),
        out,
        strategies=tuple(_split_list(strategies, "--strategies")),
        max_distance=max_distance,
        log=_log,
    )
    _print_study(doc, out)


def _option_study(study: str, cfg: Any, values: list[Any], out: Path) -> None:
    from ..eval.studies import option_study

    _print_study(option_study(cfg, study, values, out, log=_log), out)


@study_app.command("top-k")
@run_options
def top_k_cmd(
    out: StudyOut,
    cfg: Any = None,
    values: Annotated[str, typer.Option("--values", help="memories per tool call")] = "1,3,5,10,20",
) -> None:
    """Accuracy and cost as the memories returned per tool call grow (the top-k sweep)."""
    _option_study("top-k", cfg, _ints(values, "--values"), out)


@study_app.command("scores")
@run_options
def scores_cmd(out: StudyOut, cfg: Any = None) -> None:
    """Accuracy with the similarity scores shown to the model, and hidden from it."""
    _option_study("scores", cfg, [True, False], out)


@study_app.command("time-mode")
@run_options
def time_mode_cmd(out: StudyOut, cfg: Any = None) -> None:
    """Accuracy with the time tool looking forward from the asked time, and centred on it."""
    _option_study("time-mode", cfg, ["forward", "centred"], out)


@study_app.command("tool-calls")
@run_options
def tool_calls_cmd(
    out: StudyOut,
    cfg: Any = None,
    values: Annotated[str, typer.Option("--values", help="tool-call budgets")] = "0,1,3,5,10",
) -> None:
    """Accuracy and cost as the tool-call budget grows."""
    _option_study("tool-calls", cfg, _ints(values, "--values"), out)


@study_app.command("embedders")
def embedders_cmd(
    labels: Annotated[
        Path, typer.Option("--labels", help="labelled frames (e.g. benchmarks/data/tum_labels.json)")
    ],
    images: Annotated[Path, typer.Option("--images", help="folder holding the labelled frame files")],
    embedders: Annotated[
        str, typer.Option("--embedders", help="comma-separated specs: offline,hf:PATH,...")
    ] = "offline",
    k: Annotated[int, typer.Option("--k", help="precision at k")] = 5,
    min_positives: Annotated[
        int, typer.Option("--min-positives", help="objects seen in fewer frames are left out")
    ] = 3,
    out: Annotated[
        Path | None, typer.Option("--out", "-o", help="folder for study.json (then: eval report)")
    ] = None,
) -> None:
    """Text->image and image->image retrieval quality (mAP, P@k) per embedder on labelled frames."""
    from ..eval.retrieval import embedder_study

    doc = embedder_study(
        labels, images, _split_list(embedders, "--embedders"), k=k, min_positives=min_positives, out=out
    )
    table = Table(title=f"retrieval on {doc['frames']} labelled frames, {len(doc['objects'])} objects")
    for col in ("embedder", "direction", "mAP", "mAP small", f"P@{k}", "images/s"):
        table.add_column(col)
    for p in doc["points"]:
        table.add_row(
            esc(p["embedder"]),
            p["direction"],
            f"{p['mAP']:.3f}",
            f"{p['mAP_small']:.3f}",
            f"{p['P@k']:.3f}",
            f"{p['images_per_s'] or 0:.1f}",
        )
    for direction, c in doc["chance"].items():
        table.add_row("random ranking", direction, f"{c:.3f}", "", "", "")
    out_console().print(table)
    if out is not None:
        console.print(
            esc(f"wrote {out / 'study.json'}; chart: ravenmem eval report {out} --out {out / 'report.md'}")
        )


def register(app: typer.Typer) -> None:
    """Add the `eval` command group to the main app."""
    app.add_typer(eval_app, name="eval")
