"""`ravenmem eval`: run benchmarks, write reports, run the studies.

ravenmem eval --dataset raven-qa:/data/RAVEN_QA/real_world --method raven --vlm gemini-2.5-flash --seeds 3
ravenmem eval --dataset tum:../shared/data/tum_fr1_rpy --queries benchmarks/data/tum_queries.json --method offline
ravenmem eval report runs/2026-11-21/ --out report.md
ravenmem eval study compression --dataset ... --method offline --strides 1,5,25,250 --out runs/compression
ravenmem eval study top-k --dataset ... --method raven --vlm ... --values 1,3,5,10 --out runs/topk
ravenmem eval study embedders --labels benchmarks/data/tum_labels.json --images DIR/rgb --embedders offline,hf:PATH
ravenmem eval judge runs/2026-11-21/navqa_raven --judge gpt-4o-mini

Every command that runs questions takes the same run options. They are not declared here: each
is a field of the typed configuration (`ravenmem.eval.config`, declared with `option(...)`), and
`with_options` turns those fields into the command's options; `build_run_config` turns the values
given back into the `RunConfig`.
"""

from __future__ import annotations

import functools
import inspect
import json
import sys
import typing
from collections.abc import Callable
from pathlib import Path
from typing import Annotated, Any, TypeVar

import typer
from rich.console import Console
from rich.table import Table

from ..errors import InputError
from ..eval.config import SECTIONS, RunConfig, build_run_config, option_name, options_of, thresholds_from
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
RUN_SECTIONS = ("dataset", "methods", "models", "memory", "thresholds", "run")
_SIMPLE = (bool, int, float, str)


def _section(name: str) -> type:
    return RunConfig if name == "run" else SECTIONS[name]


def _cli_type(cls: type, f: Any) -> Any:
    """The type the command line takes for a config field: the option's `cli`, else the
    field's own simple type; always optional, so that "not given" is None."""
    typ = f.metadata.get("cli")
    if typ is None:
        hint = typing.get_type_hints(cls)[f.name]
        args = [a for a in typing.get_args(hint) if a is not type(None)]
        typ = hint if hint in _SIMPLE else (args[0] if len(args) == 1 and args[0] in _SIMPLE else None)
        if typ is None:
            raise TypeError(f"{cls.__name__}.{f.name}: give option(cli=...) for the type {hint}")
    return typ | None


def option_fields(sections: tuple[str, ...] = RUN_SECTIONS) -> list[tuple[str, str, Any]]:
    """(parameter name, section, field) of every option of these config sections."""
    out = [(option_name(f), sec, f) for sec in sections for f in options_of(_section(sec))]
    names = [n for n, _, _ in out]
    if len(set(names)) != len(names):
        raise TypeError(
            f"two options share a parameter name: {sorted(n for n in names if names.count(n) > 1)}"
        )
    return out


def with_options(*sections: str) -> Callable[[F], F]:
    """Give a command the options of these config sections (`RUN_SECTIONS` by default). Its own
    parameters stay; the options' values reach it as `cfg: RunConfig` (built by
    `build_run_config`), or, when it has a `given` parameter, as that dict (None = not given)."""
    chosen = tuple(sections) or RUN_SECTIONS

    def deco(fn: F) -> F:
        sig = inspect.signature(fn, eval_str=True)
        raw = "given" in sig.parameters
        own = [p for p in sig.parameters.values() if p.name not in ("cfg", "given")]
        opts = option_fields(chosen)
        shared = [
            inspect.Parameter(
                name,
                inspect.Parameter.KEYWORD_ONLY,
                default=None,
                annotation=Annotated[
                    _cli_type(_section(sec), f),
                    typer.Option(*f.metadata["flag"].split(), help=f.metadata["help"]),
                ],
            )
            for name, sec, f in opts
        ]

        @functools.wraps(fn)
        def wrapper(**kw: Any) -> Any:
            if getattr(kw.get("ctx"), "invoked_subcommand", None) is not None:
                return None  # `eval report ...`: the group's callback has nothing to run
            values = {name: kw.pop(name) for name, _, _ in opts}
            if raw:
                return fn(given=values, **kw)
            return fn(cfg=build_run_config(values), **kw)

        params = [p.replace(kind=inspect.Parameter.KEYWORD_ONLY) for p in own] + shared
        wrapper.__signature__ = inspect.Signature(params)  # type: ignore[attr-defined]
        wrapper.__annotations__ = {p.name: p.annotation for p in params}
        return wrapper  # type: ignore[return-value]

    return deco


run_options = with_options()


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


def _log(msg: str) -> None:
    console.print(esc(msg), highlight=False)


def _print_summary(summary: dict[str, Any], json_out: bool) -> None:
    if json_out:
        sys.stdout.write(json.dumps(summary, indent=2, default=str) + "\n")
        return
    from ..eval.report import fmt_num, fmt_pct

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
            fmt_pct(g["accuracy"]),
            fmt_pct(g.get("frame_accuracy")),
            fmt_pct(g.get("position_accuracy")),
            fmt_num(g["pos_error_m"]),
            fmt_num(g["time_error_min"]),
            fmt_num(g["alpha"], 3),
            fmt_num(g["images_per_q"], 1),
            fmt_num(g["tokens_per_q"], 0),
            fmt_num(g["seconds_per_q"], 2),
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
    given: Any = None,
    out: Annotated[
        Path | None, typer.Option("--out", "-o", help="run folder (default runs/<date>/<name>)")
    ] = None,
    name: Annotated[str | None, typer.Option("--name", help="run name under runs/<date>/")] = None,
    runs_dir: Annotated[Path, typer.Option("--runs-dir", help="parent of dated run folders")] = Path("runs"),
    replay: Annotated[
        Path | None,
        typer.Option(
            "--replay",
            help="re-score a finished run folder from its recorded answers and model replies, with no "
            "model; its settings are the defaults, and a changed setting that needs new replies is refused",
        ),
    ] = None,
    json_out: Annotated[bool, typer.Option("--json", help="print the summary as JSON")] = False,
) -> None:
    """Evaluate methods on a benchmark: one JSONL row per answer in the run folder, then a summary."""
    from ..eval.config import OutputConfig
    from ..eval.replay import replay_run
    from ..eval.runner import Runner

    if replay is not None:
        summary = replay_run(replay, given, out=out, log=_log)
    else:
        cfg = build_run_config(given)
        cfg.output = OutputConfig(out=str(out) if out else None, runs_dir=str(runs_dir), name=name)
        summary = Runner(cfg, log=_log).run()
    _print_summary(summary, json_out)
    if not json_out and summary.get("run_dir"):
        run_dir = summary["run_dir"]
        console.print(
            esc(
                f"rows: {Path(run_dir) / 'answers.jsonl'}; report: ravenmem eval report {run_dir} --out report.md"
            )
        )


@eval_app.command("report")
@with_options("thresholds")
def report_cmd(
    run_dir: Annotated[
        Path, typer.Argument(help="a run folder, or a folder of runs (e.g. runs/2026-11-21/)")
    ],
    given: Any = None,
    out: Annotated[
        Path, typer.Option("--out", "-o", help="markdown file; PNGs go to <stem>_figs/ beside it")
    ] = Path("report.md"),
) -> None:
    """Markdown tables (method x embedder x VLM, per category, split, horizon, cost, and the RAVEN
    authors' published figures beside our rows) and PNG plots; the threshold options re-score the
    answers (default: the run's own)."""
    from ..eval.report import paper_lines, write_report
    from ..eval.runner import read_rows, run_thresholds

    thr = thresholds_from(given, run_thresholds(run_dir))
    path = write_report(run_dir, out, thresholds=thr)
    rows = read_rows(run_dir) if next(Path(run_dir).rglob("answers.jsonl"), None) else []
    for line in paper_lines(rows):
        console.print(esc(f"beside the paper: {line}"))
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
    from ..eval.recording import MODEL_IO, ModelLog, RecordingClient
    from ..eval.runner import rejudge

    jc = VLMConfig.resolve(model=judge, base_url=judge_base_url)
    n = rejudge(run_dir, Judge(jc, client=RecordingClient(jc, ModelLog(Path(run_dir) / MODEL_IO))))
    console.print(esc(f"judged {n} text answer(s) in {run_dir}"))


# ------------------------------------------------------------------------------------ studies
StudyOut = Annotated[
    Path, typer.Option("--out", "-o", help="study folder (a run folder per setting + study.json)")
]


def _print_study(doc: dict[str, Any], out: Path) -> None:
    from ..eval.report import fmt_num, fmt_pct

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
            fmt_pct(p["accuracy"]),
            fmt_pct(p.get("frame_accuracy")),
            fmt_pct(p.get("position_accuracy")),
            fmt_num(p["alpha"], 3),
            fmt_num(p["images_per_q"], 1),
            fmt_num(p["tokens_per_q"], 0),
            fmt_num(p["tool_calls_per_q"], 1),
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
    """The ordering study: accuracy with the time tool looking forward from the asked time,
    centred on it, and listing the memories nearest to it first (the paper's three orderings)."""
    _option_study("time-mode", cfg, ["forward", "centred", "nearest"], out)


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
