"""`ravenmem ask` (question answering over a memory) and `ravenmem caption` (the caption baseline's
ingest step). VLM settings come from flags > RAVENMEM_VLM_* environment > ~/.config/ravenmem/config.toml."""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path
from typing import Annotated, Any

import typer
from rich.console import Console
from rich.table import Table

from ..agent.config import PROVIDERS, RESPONSE_FORMATS, TOOL_MODES
from ..timeparse import fmt_time
from ._console import esc, out_console, rounded
from .options import (
    CONFIG,
    COUNT,
    IMAGE_SIDE,
    MEMORY_ID,
    NAME,
    OFFSET,
    OUTPUT,
    PICTURE,
    POINT,
    RETRIES,
    ROBOT_RADIUS,
    SEED,
    TEMPERATURE,
    TIMEOUT,
    TOOL_CALLS,
    TOP_K,
    Force,
    MemoryOpt,
    MemoryOrServerOpt,
    choice,
)

BaseUrlOpt = Annotated[
    str | None, typer.Option("--base-url", help="OpenAI-compatible endpoint, e.g. http://localhost:8000/v1")
]
ModelOpt = Annotated[str | None, NAME, typer.Option("--model", help="VLM model name")]
KeyOpt = Annotated[
    str | None, typer.Option("--api-key", help="API key (default: RAVENMEM_VLM_API_KEY / OPENAI_API_KEY)")
]
ConfigOpt = Annotated[
    Path | None, CONFIG, typer.Option("--config", help="config file (default ~/.config/ravenmem/config.toml)")
]
TimeoutOpt = Annotated[
    float | None, TIMEOUT, typer.Option("--timeout", help="seconds per VLM request, wall clock (default 60)")
]
RetriesOpt = Annotated[int | None, RETRIES, typer.Option("--max-retries", help="retries on 429/5xx/timeouts")]
SegmentOpt = Annotated[
    int | None,
    COUNT,
    typer.Option(
        "--segment-frames", help="caption: keyframes per caption (default: the keyframes of each 3 s)"
    ),
]
ProviderOpt = Annotated[
    str | None,
    choice(*PROVIDERS),
    typer.Option(help="openai | vllm | ollama | llama.cpp | gemini: that server's documented settings"),
]
ImageSideOpt = Annotated[
    int | None,
    IMAGE_SIDE,
    MEMORY_ID,
    NAME,
    typer.Option("--image-max-side", help="longest side in px of images sent to the model (0 = as stored)"),
]


# the options of `ravenmem ask`, one alias each (the command reads as its list of options)
QuestionArg = Annotated[str, typer.Argument(help="the question, e.g. 'Where did I leave the red backpack?'")]
ImageOpt = Annotated[Path | None, typer.Option(help="a query image ('where did I see this?')")]
ImageIdOpt = Annotated[
    int | None, MEMORY_ID, typer.Option(help="use this memory's picture as the query picture")
]
OfflineOpt = Annotated[bool, typer.Option("--offline", help="no VLM: the offline reasoner")]
MethodOpt = Annotated[
    str | None,
    typer.Option(help="raven | offline | embedder-only | vlm-only | caption | random (default raven)"),
]
PresetOpt = Annotated[
    str | None,
    typer.Option(
        help="raven-qa-human | raven-qa-robot | raven-qa-robot-open | navqa | findingdory: the paper's settings"
    ),
]
ToolModeOpt = Annotated[
    str | None,
    choice(*TOOL_MODES),
    typer.Option(help="auto | native | json (JSON-in-prompt, no function calling)"),
]
TopKOpt = Annotated[
    str | None,
    TOP_K,
    typer.Option("--top-k", help="memories per tool call: N, or per tool 'text=30,time=200' (default 5)"),
]
CallsOpt = Annotated[
    int | None, TOOL_CALLS, typer.Option(help="tool calls before the model must answer (default 3)")
]
TemperatureOpt = Annotated[
    float | None, TEMPERATURE, typer.Option(help="sampling temperature sent to the model")
]
SeedOpt = Annotated[int | None, SEED, typer.Option(help="seed sent to the model (and the random baseline)")]
HideScoresOpt = Annotated[
    bool, typer.Option("--hide-scores", help="do not show similarity scores/distances to the model")
]
TimeModeOpt = Annotated[
    str | None, typer.Option(help="forward | centred | nearest: the time tool's window (default forward)")
]
FramesOpt = Annotated[
    int | None,
    COUNT,
    typer.Option(help="vlm-only: most frames in the prompt (all memories if fewer; default 32)"),
]
TraceOpt = Annotated[
    Path | None, OUTPUT, typer.Option(help="save the full request/response trace (JSON) here")
]
QuestionTimeoutOpt = Annotated[
    float | None, TIMEOUT, typer.Option(help="seconds for the whole question, wall clock (default 300)")
]
SheetOpt = Annotated[
    Path | None, PICTURE, typer.Option(help="also draw the evidence as a contact sheet (PNG) here")
]
JsonOpt = Annotated[bool, typer.Option("--json", help="machine-readable output")]
ServerOpt = Annotated[
    str | None, typer.Option("--server", help="URL of a running `ravenmem serve` (or RAVENMEM_SERVER)")
]
NavigateOpt = Annotated[
    bool,
    typer.Option(
        "--navigate",
        help="also plan (A* on the memory's map) from the robot's last pose to the answer's "
        "position and heading; prints the path and the goal as a Nav2 PoseStamped",
    ),
]
FromOpt = Annotated[
    str | None, POINT, typer.Option("--from", help="with --navigate: start 'x,y' in map metres")
]
RadiusOpt = Annotated[
    float | None,
    ROBOT_RADIUS,
    typer.Option(help="with --navigate: robot radius in metres (default: the map's)"),
]
AllowOpt = Annotated[
    bool,
    typer.Option(
        "--allow-unsupported",
        help="use (and with --navigate, drive to) a position farther than --max-position-offset "
        "from every memory the model was shown",
    ),
]
OffsetOpt = Annotated[
    float | None,
    OFFSET,
    typer.Option(
        help="metres from every memory shown beyond which a model's position is unsupported (default 3)"
    ),
]
VisionOpt = Annotated[
    bool | None,
    typer.Option(
        "--vision/--no-vision",
        help="the model sees pictures / gets memories as text (default: pictures, text if refused)",
    ),
]
FormatOpt = Annotated[
    str | None,
    choice(*RESPONSE_FORMATS),
    typer.Option(help="none | json_object | json_schema | json_object_schema: constrain the answer"),
]
FirstToolOpt = Annotated[
    str | None, typer.Option(help="a tool the model must call first (tool_choice naming it)")
]

# the model's connection: {VLMConfig setting: option parameter}; never part of a request
MODEL_PARAMS = {
    "base_url": "base_url",
    "model": "model_name",
    "api_key": "api_key",
    "tool_mode": "tool_mode",
    "timeout": "timeout",
    "question_timeout": "question_timeout",
    "max_retries": "max_retries",
    "provider": "provider",
    "vision": "vision",
    "response_format": "response_format",
    "first_tool": "first_tool",
}


def ask(
    question: QuestionArg,
    memory: MemoryOrServerOpt = None,
    image: ImageOpt = None,
    image_memory_id: ImageIdOpt = None,
    offline: OfflineOpt = False,
    method: MethodOpt = None,
    preset: PresetOpt = None,
    base_url: BaseUrlOpt = None,
    model_name: ModelOpt = None,
    api_key: KeyOpt = None,
    tool_mode: ToolModeOpt = None,
    top_k: TopKOpt = None,
    max_tool_calls: CallsOpt = None,
    temperature: TemperatureOpt = None,
    seed: SeedOpt = None,
    hide_scores: HideScoresOpt = False,
    time_mode: TimeModeOpt = None,
    frames: FramesOpt = None,
    segment_frames: SegmentOpt = None,
    image_max_side: ImageSideOpt = None,
    trace: TraceOpt = None,
    timeout: TimeoutOpt = None,
    question_timeout: QuestionTimeoutOpt = None,
    max_retries: RetriesOpt = None,
    config: ConfigOpt = None,
    sheet: SheetOpt = None,
    force: Force = False,
    json_out: JsonOpt = False,
    server: ServerOpt = None,
    navigate: NavigateOpt = False,
    from_: FromOpt = None,
    robot_radius: RadiusOpt = None,
    allow_unsupported: AllowOpt = False,
    max_position_offset: OffsetOpt = None,
    provider: ProviderOpt = None,
    vision: VisionOpt = None,
    response_format: FormatOpt = None,
    first_tool: FirstToolOpt = None,
) -> None:
    """Answer a question from a memory: position, time, yes/no, duration or text, with evidence.
    Exit 1 when the question failed or its position is unsupported (see --allow-unsupported);
    with --navigate, exit 0 means a path to the answer was planned (1: answered, no path)."""
    from ravenmem.errors import InputError
    from ravenmem.server.client import resolve_server
    from ravenmem.viz.sheet import answer_title

    from .source import open_source
    from .source import sheet as draw_sheet

    given = dict(locals())  # every option by its parameter's name
    if offline and method not in (None, "offline"):
        raise InputError(f"--offline and --method {method} contradict each other")
    if (from_ is not None or robot_radius is not None) and not navigate:
        raise InputError("--from and --robot-radius apply with --navigate only")
    given |= {"method": "offline" if offline else method, "show_scores": False if hide_scores else None}
    args = _ask_args({field: given[param] for field, param in ASK_PARAMS.items()})
    model = {key: given[param] for key, param in MODEL_PARAMS.items()}
    if resolve_server(server, memory):  # a running service answers, with its own model
        if navigate:
            raise InputError("--navigate plans on a local memory's map: give --memory, not --server")
        if any(v is not None for v in [*model.values(), config, trace, segment_frames]):
            raise InputError(
                "with --server the service's own VLM settings are used: leave out the model's "
                "connection flags (--base-url, --model, --provider, ...), --config, --trace and --segment-frames"
            )
    local = {"trace_path": trace, "segment_frames": segment_frames}
    with open_source(memory, server, model=model, config=config, options=local) as src:
        data, refusal, code = src.ask_json(args, image)
        if sheet is not None:
            draw_sheet(src, data["evidence"], sheet, answer_title(data), src.t0())
            data["sheet"] = str(sheet)
    _output(data, json_out, refusal, code)


# every field of the one ask request (`runtime.ask.AskArgs`) and the option of `ravenmem ask`
# that sets it (a test ties them): what a question is, the same here as over HTTP, MCP and ROS
ASK_OPTIONS = {
    "question": "QUESTION",
    "image": "--image",
    "image_memory_id": "--image-memory-id",
    "method": "--method",
    "preset": "--preset",
    "top_k": "--top-k",
    "max_tool_calls": "--max-tool-calls",
    "temperature": "--temperature",
    "seed": "--seed",
    "show_scores": "--hide-scores",
    "time_mode": "--time-mode",
    "frames": "--frames",
    "image_max_side": "--image-max-side",
    "max_position_offset": "--max-position-offset",
    "navigate": "--navigate",
    "start": "--from",
    "robot_radius": "--robot-radius",
    "allow_unsupported": "--allow-unsupported",
}


# {AskArgs field: the parameter of `ask` that holds it} (`image` is read from its file)
ASK_PARAMS = {f: ("from_" if f == "start" else f) for f in ASK_OPTIONS if f not in ("image",)}


def _ask_args(given: dict[str, Any]) -> Any:
    """The options as the one ask request (`AskArgs`), checked there: a question longer than the
    bound, an unknown method or preset is one line."""
    from ravenmem.agent import parse_top_k
    from ravenmem.agent.base import METHODS
    from ravenmem.runtime.ask import AskArgs

    from .nav import parse_start

    if given["method"] is not None:
        METHODS.get(given["method"])  # an unknown method: one line, before any request
    given["top_k"] = parse_top_k(given["top_k"])
    given["start"] = parse_start(given["start"])
    return AskArgs.check({k: v for k, v in given.items() if v is not None})


def _output(data: dict[str, Any], json_out: bool, refusal: str | None, code: int) -> None:
    """The answer (card or JSON) on stdout; a refused result ends with its one line (the question
    failed: ..., unsupported answer: ...) on stderr, and exit 1."""
    nav = data.get("navigation")
    if json_out:
        if refusal:
            data["refusal"] = refusal
        sys.stdout.write(json.dumps(data, indent=2) + "\n")
    else:
        _render(data)
        if data.get("sheet"):
            out_console().print(f"contact sheet: {esc(str(data['sheet']))}", highlight=False)
        if nav is not None:
            _render_navigation(nav)
    if refusal:
        sys.stderr.write(" ".join(refusal.split()) + "\n")
    if code:
        raise typer.Exit(code)


def _render_navigation(nav: dict[str, Any]) -> None:
    con = out_console()
    if not nav["ok"]:
        what = f" ({nav['problem']})" if nav.get("problem") else ""
        con.print(f"[bold]navigate:[/] [red]no path{what}[/]: {esc(nav['reason'])}", highlight=False)
        return
    (sx, sy), (gx, gy, gyaw) = nav["start"], nav["goal"]
    heading = nav.get("heading") or {}
    con.print(
        f"[bold]navigate:[/] A* path {nav['path_length_m']:.2f} m, {len(nav['waypoints'])} waypoints, "
        f"from ({sx:.2f}, {sy:.2f}) to ({gx:.2f}, {gy:.2f}) facing {math.degrees(gyaw):.0f} deg "
        f"({esc(heading.get('reason', ''))}; frame {esc(nav['frame_id'])}, map {esc(nav.get('map_id') or '')})",
        highlight=False,
    )
    for note in nav.get("notes", []):
        con.print(f"[yellow]note:[/] {esc(note)}", highlight=False)
    sys.stdout.write(json.dumps(rounded(nav["pose_stamped"])) + "\n")


def _render(a: dict[str, Any]) -> None:
    from .main import short_path

    con = out_console()
    status = "[red]FAILED[/]" if a["failed"] else ("found" if a["found"] else "[yellow]not found[/]")
    if a.get("unsupported"):
        status += "  [red]UNSUPPORTED[/]"
    con.print(f"[bold]type:[/] {esc(a['question_type'])}   [bold]method:[/] {esc(a['method'])}   {status}")
    ran = [f"model {a['model']} at {a['model_host']}" if a.get("model") else ""]
    ran += [
        f"embedder {a['embedder']}" if a.get("embedder") else "",
        f"preset {a['preset']}" if a.get("preset") else "",
    ]
    if any(ran):
        con.print("[bold]ran:[/] " + esc(", ".join(r for r in ran if r)), highlight=False)
    con.print(f"[bold]answer:[/] {esc(a['text'])}", highlight=False)
    if a.get("position"):
        x, y, z = a["position"]
        yaw = f"{math.degrees(a['yaw']):.0f} deg" if a.get("yaw") is not None else "-"
        src = f"position from {a['position_source']}, yaw from {a['yaw_source']}"
        if a.get("support_distance") is not None:
            src += f", {a['support_distance']:.1f} m from the nearest memory shown"
        con.print(f"[bold]x y z yaw:[/] {x:.2f} {y:.2f} {z:.2f} {yaw}   ({esc(src)})")
    if a.get("time") is not None:
        con.print(f"[bold]time seen:[/] {fmt_time(a['time'])}")
    if a.get("duration") is not None:
        con.print(f"[bold]duration:[/] {a['duration']:.1f} s")
    if a.get("yes") is not None:
        con.print(f"[bold]yes/no:[/] {'yes' if a['yes'] else 'no'}")
    if a.get("error"):
        con.print(f"[red]error:[/] {esc(a['error'])}", highlight=False)
    if a["evidence"]:
        table = Table(title="evidence memories")
        for col in ("id", "time (UTC)", "x", "y", "z", "yaw deg", "score", "image"):
            table.add_column(col, justify="left" if col in ("time (UTC)", "image") else "right")
        for e in a["evidence"]:
            score = "" if e.get("score") is None else f"{e['score']:.3f}"
            table.add_row(
                str(e["id"]),
                fmt_time(e["t"]),
                f"{e['x']:.2f}",
                f"{e['y']:.2f}",
                f"{e['z']:.2f}",
                f"{math.degrees(e['yaw']):.0f}",
                score,
                esc(short_path(e.get("image_file"))),  # relative to here, as `search` shows them
            )
        con.print(table)
    c = a["cost"]
    con.print(
        f"[bold]tool calls used:[/] {c['tool_calls']}   memories shown {c['memories_shown']}/{c['memories_total']} "
        f"(alpha {c['alpha']:.4f})   images {c['images']} ({c['image_bytes'] / 1024:.0f} KiB)   tokens {c['prompt_tokens']}+{c['completion_tokens']}   "
        f"{c['wall_s']:.2f} s"
    )
    if a.get("reasoning"):
        con.print(f"[dim]reasoning: {esc(a['reasoning'])}[/]", highlight=False)
    for note in a.get("notes", []):
        con.print(f"[yellow]note:[/] {esc(note)}", highlight=False)


def caption(
    memory: MemoryOpt,
    base_url: BaseUrlOpt = None,
    model: ModelOpt = None,
    api_key: KeyOpt = None,
    segment_frames: SegmentOpt = None,
    image_max_side: ImageSideOpt = None,
    timeout: TimeoutOpt = None,
    max_retries: RetriesOpt = None,
    config: ConfigOpt = None,
    json_out: Annotated[bool, typer.Option("--json", help="machine-readable output")] = False,
) -> None:
    """Caption the memory in segments of consecutive keyframes with a VLM (the caption baseline);
    re-running captions only new segments."""
    import ravenmem
    from ravenmem.agent import VLMConfig, caption_memories
    from ravenmem.agent.methods import require_model
    from ravenmem.memory.folder import CAPTIONS

    vlm = VLMConfig.resolve(
        config_path=config,
        base_url=base_url,
        model=model,
        api_key=api_key,
        timeout=timeout,
        max_retries=max_retries,
    )
    require_model("caption", vlm)
    seg = segment_frames  # None: segments of 3 s
    with ravenmem.open(memory) as mem:
        n = caption_memories(mem, vlm, segment_frames=seg, image_max_side=image_max_side or 0)
        total = mem.count()
    out = {
        "captioned_now": n,
        "memories": total,
        "segment_frames": seg,
        "file": str(Path(memory) / CAPTIONS),
    }
    if json_out:
        sys.stdout.write(json.dumps(out, indent=2) + "\n")
    else:
        Console().print(
            f"captioned {n} segments of {f'{seg} keyframes' if seg else '3 s'} ({total} memories); captions in {esc(out['file'])}",
            highlight=False,
        )


def register(app: typer.Typer) -> None:
    """Add `ask` and `caption` to the ravenmem command."""
    app.command("ask")(ask)
    app.command("caption")(caption)
