"""`ravenmem eval`: run benchmarks, write reports, run the compression and coverage studies.

ravenmem eval --dataset raven-qa:/data/RAVEN_QA/real_world --method raven --vlm gemini-2.5-flash --seeds 3
ravenmem eval --dataset tum:../shared/data/tum_fr1_rpy --queries benchmarks/data/tum_queries.json --method offline
ravenmem eval report runs/2026-11-21/ --out report.md
ravenmem eval study compression --dataset ... --method offline --strides 1,5,25,250 --out runs/compression
ravenmem eval study coverage --dataset raven-qa:sim_export --method offline --fractions 0.25,0.5,1 --out runs/cov
ravenmem eval judge runs/2026-11-21/navqa_raven --judge gpt-4o-mini
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Annotated, Any

import typer
from rich.console import Console
from rich.table import Table

from ..errors import InputError
from ._console import esc, out_console

eval_app = typer.Typer(help="Benchmarks (RAVEN-QA, NaVQA, FindingDory, your own questions), reports and studies.",
                       no_args_is_help=False)  # fmt: skip
study_app = typer.Typer(help="Accuracy vs keyframe sparsification (compression) or exploration coverage.",
                        no_args_is_help=True)  # fmt: skip
eval_app.add_typer(study_app, name="study")
console = Console(stderr=True)

DatasetOpt = Annotated[
    str | None,
    typer.Option(
        "--dataset",
        "-d",
        help="NAME:PATH, NAME = raven-qa | navqa | findingdory | tum | video | folder | rosbag | memory | queries",
    ),
]
MethodOpt = Annotated[
    str | None,
    typer.Option(
        "--method", help="comma-separated: raven, offline, embedder-only, vlm-only, caption, random"
    ),
]
QueriesOpt = Annotated[
    Path | None,
    typer.Option("--queries", help="our questions.json for tum:/video:/folder:/rosbag:/memory: datasets"),
]
EmbedderOpt = Annotated[
    str, typer.Option("--embedder", help="offline | open_clip:MODEL/TAG | hf:NAME_OR_PATH")
]
VlmOpt = Annotated[
    str | None,
    typer.Option("--vlm", help="VLM model name (endpoint from --vlm-base-url / RAVENMEM_VLM_BASE_URL)"),
]
VlmUrlOpt = Annotated[
    str | None, typer.Option("--vlm-base-url", help="OpenAI-compatible endpoint for the VLM")
]
SeedsOpt = Annotated[
    int, typer.Option("--seeds", help="repeat every question with seeds 0..N-1 (mean ± std)")
]
OutOpt = Annotated[Path | None, typer.Option("--out", "-o", help="run folder (default runs/<date>/<name>)")]
CacheOpt = Annotated[Path, typer.Option("--cache-dir", help="where memories and embeddings are cached")]
WorkersOpt = Annotated[int, typer.Option("--workers", help="questions answered in parallel")]
KeyframesOpt = Annotated[
    str | None,
    typer.Option("--keyframes", help="e.g. 'stride=5,fps=2,max_similarity=0.95' (default: all frames)"),
]
TopKOpt = Annotated[
    str | None,
    typer.Option("--top-k", help="memories per tool call: N, or per tool 'time=200,text=30,position=1'"),
]
ToolCallsOpt = Annotated[
    int | None, typer.Option("--max-tool-calls", help="tool calls before the model must answer")
]
PosThrOpt = Annotated[
    str | None,
    typer.Option("--pos-threshold", help="metres: one number, or per RAVEN-QA split 'real_world=3,sim=1'"),
]
LimitOpt = Annotated[int | None, typer.Option("--limit", help="only the first N questions (smoke runs)")]
EpisodesOpt = Annotated[
    str | None, typer.Option("--episodes", help="only episodes whose id matches this glob")
]


def _split_list(text: str | None, what: str) -> list[str]:
    items = [x.strip() for x in (text or "").split(",") if x.strip()]
    if not items:
        raise InputError(f"{what}: give at least one value")
    return items


def parse_top_k(text: str | None) -> int | dict[str, int] | None:
    """'5' -> 5; 'time=200,text=30,position=1' -> {'time': 200, 'text': 30, 'position': 1}."""
    if text is None:
        return None
    try:
        if "=" not in text:
            return int(text)
        out = {}
        for part in _split_list(text, "--top-k"):
            k, _, v = part.partition("=")
            out[k.strip()] = int(v)
        return out
    except ValueError:
        raise InputError(f"--top-k: expected N or tool=N,... with whole numbers, got {text!r}") from None


def _floats(text: str, what: str) -> list[float]:
    try:
        return [float(x) for x in _split_list(text, what)]
    except ValueError:
        raise InputError(f"{what}: expected comma-separated numbers, got {text!r}") from None


def build_config(dataset: str | None, method: str | None, **kw: Any) -> Any:
    """RunConfig from CLI values (shared by `eval` and the study commands)."""
    from ..eval.runner import RunConfig

    if not dataset:
        raise InputError("--dataset NAME:PATH is required (e.g. raven-qa:/data/RAVEN_QA/real_world)")
    methods = _split_list(method, "--method")
    thresholds: dict[str, Any] = {}
    dataset_opts: dict[str, Any] = {k: v for k, v in kw.pop("dataset_opts", {}).items() if v is not None}
    pos = kw.pop("pos_threshold", None)
    if pos:
        if "=" in pos:
            if not dataset.startswith(("raven-qa:", "ravenqa:")):
                raise InputError("--pos-threshold split=value,... is for raven-qa datasets; give one number")
            per = {}
            for part in _split_list(pos, "--pos-threshold"):
                k, _, v = part.partition("=")
                per[k.strip()] = _floats(v, "--pos-threshold")[0]
            dataset_opts["pos_threshold"] = per
        else:
            thresholds["position_m"] = _floats(pos, "--pos-threshold")[0]
    for key, scale in (("time_min", 60.0), ("duration_min", 60.0)):
        v = kw.pop(key, None)
        if v is not None:
            thresholds[key.replace("_min", "_s")] = v * scale
    for key in ("frame_s", "planar"):
        v = kw.pop(key, None)
        if v is not None and v is not False:
            thresholds[key] = v
    method_opts = {k: v for k, v in kw.pop("method_opts", {}).items() if v is not None}
    q = kw.pop("queries", None)
    rest: dict[str, Any] = {k: (str(v) if isinstance(v, Path) else v) for k, v in kw.items() if v is not None}
    return RunConfig(dataset=dataset, methods=methods, queries=str(q) if q else None, thresholds=thresholds,
                     dataset_opts=dataset_opts, method_opts=method_opts,
                     **rest)  # fmt: skip


def _print_summary(summary: dict[str, Any], json_out: bool) -> None:
    if json_out:
        sys.stdout.write(json.dumps(summary, indent=2, default=str) + "\n")
        return
    from ..eval.report import _num, _pct

    table = Table(title=esc(f"{summary['rows']} answers in {summary.get('run_dir', '')}"))
    for col in ("method", "embedder", "VLM", "Q", "accuracy %", "pos err m", "time err min", "alpha", "s/q"):
        table.add_column(col)
    for g in summary["groups"]:
        table.add_row(esc(g["method"] + (f" [{g['variant']}]" if g.get("variant") else "")), esc(g["embedder"]), esc(g["vlm"]),
                      str(g["questions"]), _pct(g["accuracy"]), _num(g["pos_error_m"]), _num(g["time_error_min"]),
                      _num(g["alpha"], 3), _num(g["seconds_per_q"], 2))  # fmt: skip
    out_console().print(table)
    for g in summary["groups"]:
        if g["not_judged"]:
            console.print(
                f"{esc(g['method'])}: {g['not_judged']} text answer(s) not scored (no LLM judge; use --judge MODEL)"
            )


@eval_app.callback(invoke_without_command=True)
def eval_main(
    ctx: typer.Context,
    dataset: DatasetOpt = None,
    method: MethodOpt = None,
    queries: QueriesOpt = None,
    embedder: EmbedderOpt = "offline",
    vlm: VlmOpt = None,
    vlm_base_url: VlmUrlOpt = None,
    seeds: SeedsOpt = 1,
    out: OutOpt = None,
    name: Annotated[str | None, typer.Option("--name", help="run name under runs/<date>/")] = None,
    runs_dir: Annotated[Path, typer.Option("--runs-dir", help="parent of dated run folders")] = Path("runs"),
    cache_dir: CacheOpt = Path(".ravenmem-cache/eval"),
    workers: WorkersOpt = 4,
    keyframes: KeyframesOpt = None,
    ocr: Annotated[
        bool, typer.Option(help="read text in keyframes while building memories (slower)")
    ] = False,
    thumb_size: Annotated[int, typer.Option(help="thumbnail longer side (px) in built memories")] = 320,
    top_k: TopKOpt = None,
    max_tool_calls: ToolCallsOpt = None,
    frames: Annotated[
        int | None, typer.Option("--frames", help="vlm-only: frames sampled over the history")
    ] = None,
    pos_threshold: PosThrOpt = None,
    time_threshold: Annotated[
        float | None, typer.Option("--time-threshold", help="minutes (default 0.5)")
    ] = None,
    duration_threshold: Annotated[
        float | None, typer.Option("--duration-threshold", help="minutes (default 0.5)")
    ] = None,
    frame_tolerance: Annotated[
        float | None, typer.Option("--frame-tolerance", help="seconds either side of an accepted frame")
    ] = None,
    planar: Annotated[bool, typer.Option("--planar", help="position error in x, y only")] = False,
    judge: Annotated[str | None, typer.Option("--judge", help="LLM judge model for text answers")] = None,
    judge_base_url: Annotated[
        str | None, typer.Option("--judge-base-url", help="endpoint of the judge (default: the VLM's)")
    ] = None,
    rate: Annotated[
        float | None, typer.Option("--rate", help="raven-qa: frames per second where no timestamps are given")
    ] = None,
    tz: Annotated[
        str | None, typer.Option("--tz", help="navqa: time zone of data.csv timestamps (America/Chicago)")
    ] = None,
    split: Annotated[str | None, typer.Option("--split", help="findingdory: split name (validation)")] = None,
    limit: LimitOpt = None,
    episodes: EpisodesOpt = None,
    retry_failed: Annotated[
        bool, typer.Option("--retry-failed", help="answer again the questions whose method failed")
    ] = False,
    json_out: Annotated[bool, typer.Option("--json", help="print the summary as JSON")] = False,
) -> None:
    """Evaluate methods on a benchmark: one JSONL row per answer in the run folder, then a summary."""
    if ctx.invoked_subcommand is not None:
        return
    from ..eval.runner import Runner

    cfg = build_config(
        dataset, method, queries=queries, embedder=embedder, vlm=vlm, vlm_base_url=vlm_base_url, seeds=seeds, out=out,
        name=name, runs_dir=runs_dir, cache_dir=cache_dir, workers=workers, keyframes=keyframes, ocr=ocr,
        thumb_size=thumb_size, pos_threshold=pos_threshold, time_min=time_threshold, duration_min=duration_threshold,
        frame_s=frame_tolerance, planar=planar, judge_model=judge, judge_base_url=judge_base_url, limit=limit,
        episodes=episodes, retry_failed=retry_failed,
        method_opts={"top_k": parse_top_k(top_k), "max_tool_calls": max_tool_calls, "frames": frames},
        dataset_opts={"rate": rate, "tz": tz, "split": split},
    )  # fmt: skip
    summary = Runner(cfg, log=lambda m: console.print(esc(m), highlight=False)).run()
    _print_summary(summary, json_out)
    if not json_out:
        console.print(
            esc(
                f"rows: {Path(summary['run_dir']) / 'answers.jsonl'}; report: ravenmem eval report {summary['run_dir']} --out report.md"
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
    """Markdown tables (method x embedder x VLM, per category, per horizon) and PNG plots."""
    from ..eval.metrics import Thresholds
    from ..eval.report import _thresholds_of, write_report

    thr = _thresholds_of(run_dir)
    if pos_threshold is not None:
        thr.position_m = pos_threshold
    if time_threshold is not None:
        thr.time_s = 60.0 * time_threshold
    path = write_report(run_dir, out, thresholds=Thresholds(**thr.to_dict()))
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


def _study_config(dataset: str | None, method: str | None, queries: Path | None, embedder: str, vlm: str | None,
                  vlm_base_url: str | None, seeds: int, cache_dir: Path, workers: int, keyframes: str | None,
                  top_k: str | None, max_tool_calls: int | None, pos_threshold: str | None, limit: int | None,
                  episodes: str | None) -> Any:  # fmt: skip
    return build_config(dataset, method, queries=queries, embedder=embedder, vlm=vlm, vlm_base_url=vlm_base_url,
                        seeds=seeds, cache_dir=cache_dir, workers=workers, keyframes=keyframes,
                        pos_threshold=pos_threshold, limit=limit, episodes=episodes,
                        method_opts={"top_k": parse_top_k(top_k), "max_tool_calls": max_tool_calls})  # fmt: skip


@study_app.command("compression")
def compression_cmd(
    out: Annotated[Path, typer.Option("--out", "-o", help="study folder (one run folder per stride + study.json)")],
    strides: Annotated[str, typer.Option("--strides", help="keyframe strides")] = "1,2,5,10,25,50,100,250",
    dataset: DatasetOpt = None, method: MethodOpt = None, queries: QueriesOpt = None,
    embedder: EmbedderOpt = "offline", vlm: VlmOpt = None, vlm_base_url: VlmUrlOpt = None, seeds: SeedsOpt = 1,
    cache_dir: CacheOpt = Path(".ravenmem-cache/eval"), workers: WorkersOpt = 4, keyframes: KeyframesOpt = None,
    top_k: TopKOpt = None, max_tool_calls: ToolCallsOpt = None, pos_threshold: PosThrOpt = None,
    limit: LimitOpt = None, episodes: EpisodesOpt = None,
) -> None:  # fmt: skip
    """Accuracy vs keyframe stride (frames per memory), the sparsification curve."""
    from ..eval.studies import compression_study

    cfg = _study_config(dataset, method, queries, embedder, vlm, vlm_base_url, seeds, cache_dir, workers, keyframes,
                        top_k, max_tool_calls, pos_threshold, limit, episodes)  # fmt: skip
    try:
        values = [int(s) for s in _split_list(strides, "--strides")]
    except ValueError:
        raise InputError(f"--strides: expected whole numbers, got {strides!r}") from None
    doc = compression_study(cfg, values, out, log=lambda m: console.print(esc(m), highlight=False))
    for p in doc["points"]:
        console.print(f"stride {p['stride']:>4}: {p['memories']} memories from {p['frames']} frames "
                      f"({p['sparsification']:.1f}x), {esc(p['method'])}: {100 * (p['accuracy']['mean'] or 0):.1f}%")  # fmt: skip
    console.print(
        esc(f"wrote {out / 'study.json'}; plot: ravenmem eval report {out} --out {out / 'report.md'}")
    )


@study_app.command("coverage")
def coverage_cmd(
    out: Annotated[Path, typer.Option("--out", "-o", help="study folder (one run folder per fraction + study.json)")],
    fractions: Annotated[str, typer.Option("--fractions", help="coverage fractions in (0, 1]")] = "0.25,0.5,0.75,1.0",
    cell: Annotated[float, typer.Option("--cell", help="grid cell (m) for coverage")] = 1.0,
    dataset: DatasetOpt = None, method: MethodOpt = None, queries: QueriesOpt = None,
    embedder: EmbedderOpt = "offline", vlm: VlmOpt = None, vlm_base_url: VlmUrlOpt = None, seeds: SeedsOpt = 1,
    cache_dir: CacheOpt = Path(".ravenmem-cache/eval"), workers: WorkersOpt = 4, keyframes: KeyframesOpt = None,
    top_k: TopKOpt = None, max_tool_calls: ToolCallsOpt = None, pos_threshold: PosThrOpt = None,
    limit: LimitOpt = None, episodes: EpisodesOpt = None,
) -> None:  # fmt: skip
    """Accuracy vs the fraction of the environment explored when the questions are asked."""
    from ..eval.studies import coverage_study

    cfg = _study_config(dataset, method, queries, embedder, vlm, vlm_base_url, seeds, cache_dir, workers, keyframes,
                        top_k, max_tool_calls, pos_threshold, limit, episodes)  # fmt: skip
    doc = coverage_study(cfg, _floats(fractions, "--fractions"), out, cell=cell,
                         log=lambda m: console.print(esc(m), highlight=False))  # fmt: skip
    for p in doc["points"]:
        console.print(f"coverage {100 * p['coverage']:>3.0f}%: {p['memories']} memories, {esc(p['method'])}: "
                      f"{100 * (p['accuracy']['mean'] or 0):.1f}%")  # fmt: skip
    console.print(
        esc(f"wrote {out / 'study.json'}; plot: ravenmem eval report {out} --out {out / 'report.md'}")
    )


def register(app: typer.Typer) -> None:
    """Add the `eval` command group to the main app."""
    app.add_typer(eval_app, name="eval")
