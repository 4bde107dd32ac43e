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

from ..timeparse import fmt_time
from ._console import esc, out_console
from .options import (
    CONFIG,
    COUNT,
    IMAGE_SIDE,
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
)

MemoryOpt = Annotated[Path, typer.Option("--memory", "-m", help="memory folder")]
BaseUrlOpt = Annotated[
    str | None, typer.Option("--base-url", help="OpenAI-compatible endpoint, e.g. http://localhost:8000/v1")
]
ModelOpt = Annotated[str | None, typer.Option("--model", help="VLM model name")]
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
    typer.Option(help="openai | vllm | ollama | llama.cpp | gemini: that server's documented settings"),
]
ImageSideOpt = Annotated[
    int | None,
    IMAGE_SIDE,
    typer.Option("--image-max-side", help="longest side in px of images sent to the model (0 = as stored)"),
]


def ask(
    question: Annotated[str, typer.Argument(help="the question, e.g. 'Where did I leave the red backpack?'")],
    memory: Annotated[Path | None, typer.Option("--memory", "-m", help="memory folder (or --server)")] = None,
    image: Annotated[Path | None, typer.Option(help="a query image ('where did I see this?')")] = None,
    offline: Annotated[bool, typer.Option("--offline", help="no VLM: the offline reasoner")] = False,
    method: Annotated[
        str | None,
        typer.Option(help="raven | offline | embedder-only | vlm-only | caption | random (default raven)"),
    ] = None,
    preset: Annotated[
        str | None,
        typer.Option(
            help="raven-qa-human | raven-qa-robot | raven-qa-robot-open | navqa | findingdory: the paper's settings"
        ),
    ] = None,
    base_url: BaseUrlOpt = None,
    model: ModelOpt = None,
    api_key: KeyOpt = None,
    tool_mode: Annotated[
        str | None, typer.Option(help="auto | native | json (JSON-in-prompt, no function calling)")
    ] = None,
    top_k: Annotated[
        str | None,
        TOP_K,
        typer.Option("--top-k", help="memories per tool call: N, or per tool 'text=30,time=200' (default 5)"),
    ] = None,
    max_tool_calls: Annotated[
        int | None, TOOL_CALLS, typer.Option(help="tool calls before the model must answer (default 3)")
    ] = None,
    temperature: Annotated[
        float | None, TEMPERATURE, typer.Option(help="sampling temperature sent to the model")
    ] = None,
    seed: Annotated[
        int | None, SEED, typer.Option(help="seed sent to the model (and the random baseline)")
    ] = None,
    hide_scores: Annotated[
        bool, typer.Option("--hide-scores", help="do not show similarity scores/distances to the model")
    ] = False,
    time_mode: Annotated[
        str | None, typer.Option(help="forward | centred: the time tool's window (default forward)")
    ] = None,
    frames: Annotated[
        int | None,
        COUNT,
        typer.Option(help="vlm-only: most frames in the prompt (all memories if fewer; default 32)"),
    ] = None,
    segment_frames: SegmentOpt = None,
    image_max_side: ImageSideOpt = None,
    trace: Annotated[
        Path | None, OUTPUT, typer.Option(help="save the full request/response trace (JSON) here")
    ] = None,
    timeout: TimeoutOpt = None,
    question_timeout: Annotated[
        float | None, TIMEOUT, typer.Option(help="seconds for the whole question, wall clock (default 300)")
    ] = None,
    max_retries: RetriesOpt = None,
    config: ConfigOpt = None,
    sheet: Annotated[
        Path | None, PICTURE, typer.Option(help="also draw the evidence as a contact sheet (PNG) here")
    ] = None,
    force: Force = False,
    json_out: Annotated[bool, typer.Option("--json", help="machine-readable output")] = False,
    server: Annotated[
        str | None, typer.Option("--server", help="URL of a running `ravenmem serve` (or RAVENMEM_SERVER)")
    ] = None,
    navigate: Annotated[
        bool,
        typer.Option(
            "--navigate",
            help="also plan (A* on the memory's map) from the robot's last pose to the answer's "
            "position and heading; prints the path and the goal as a Nav2 PoseStamped",
        ),
    ] = False,
    from_: Annotated[
        str | None, POINT, typer.Option("--from", help="with --navigate: start 'x,y' in map metres")
    ] = None,
    robot_radius: Annotated[
        float | None,
        ROBOT_RADIUS,
        typer.Option(help="with --navigate: robot radius in metres (default: the map's)"),
    ] = None,
    allow_unsupported: Annotated[
        bool,
        typer.Option(
            "--allow-unsupported",
            help="use (and with --navigate, drive to) a position farther than --max-position-offset "
            "from every memory the model was shown",
        ),
    ] = False,
    max_position_offset: Annotated[
        float | None,
        OFFSET,
        typer.Option(
            help="metres from every memory shown beyond which a model's position is unsupported (default 3)"
        ),
    ] = None,
    provider: ProviderOpt = None,
    vision: Annotated[
        bool | None,
        typer.Option(
            "--vision/--no-vision",
            help="the model sees pictures / gets memories as text (default: pictures, text if refused)",
        ),
    ] = None,
    response_format: Annotated[
        str | None,
        typer.Option(help="none | json_object | json_schema | json_object_schema: constrain the answer"),
    ] = None,
    first_tool: Annotated[
        str | None, typer.Option(help="a tool the model must call first (tool_choice naming it)")
    ] = None,
) -> None:
    """Answer a question from a memory: position, time, yes/no, duration or text, with evidence.
    Exit 1 when the question failed or its position is unsupported (see --allow-unsupported);
    with --navigate, exit 0 means a path to the answer was planned (1: answered, no path)."""
    import ravenmem
    from ravenmem.agent import AskRequest, MethodOptions, QuestionFailed, VLMConfig, ask, parse_top_k
    from ravenmem.errors import InputError
    from ravenmem.imageio import read_image
    from ravenmem.server.client import ServerClient, resolve_server

    if offline and method not in (None, "offline"):
        raise InputError(f"--offline and --method {method} contradict each other")
    name = "offline" if offline else (method or "raven")
    if (from_ is not None or robot_radius is not None) and not navigate:
        raise InputError("--from and --robot-radius apply with --navigate only")
    url = resolve_server(server, memory)
    if url and navigate:
        raise InputError("--navigate plans on a local memory's map: give --memory, not --server")
    vlm_flags: dict[str, Any] = dict(
        base_url=base_url,
        model=model,
        api_key=api_key,
        tool_mode=tool_mode,
        timeout=timeout,
        question_timeout=question_timeout,
        max_retries=max_retries,
        provider=provider,
        vision=vision,
        response_format=response_format,
        first_tool=first_tool,
    )
    if url:  # a running service answers, with its own VLM settings
        local_only = [*vlm_flags.values(), config, trace, temperature, seed, time_mode, frames]
        local_only += [segment_frames, image_max_side, max_position_offset]
        if any(v is not None for v in local_only) or hide_scores:
            raise InputError(
                "with --server the service's own VLM settings are used: give only --method/--offline, "
                "--preset, --top-k, --max-tool-calls and --allow-unsupported"
            )
        MethodOptions.of(name, preset=preset).check()  # an unknown method or preset: one line, no request
        with ServerClient(url) as remote:
            method_asked = None if method is None and not offline else name
            try:
                data = remote.ask(
                    question,
                    method_asked,
                    parse_top_k(top_k),
                    max_tool_calls,
                    image,
                    preset,
                    allow_unsupported,
                )
            except QuestionFailed as e:
                if e.answer is None:
                    raise
                data, refusal = e.answer, str(e)
            else:
                refusal = ""
            if sheet is not None:
                from ravenmem.viz.sheet import answer_title, remote_sheet

                remote_sheet(data["evidence"], remote.picture, sheet, answer_title(data))
                data["sheet"] = str(sheet)
        for ev in data["evidence"]:
            ev["image_file"] = ev.get("image")
        _output(data, json_out, refusal or None, 1 if refusal else 0)
        return
    vlm = None
    if MethodOptions.of(name).needs_vlm:  # a VLM method reads the VLM settings (a model-free one never does)
        vlm = VLMConfig.resolve(config_path=config, **vlm_flags)
    opts = MethodOptions.of(
        name,
        vlm=vlm,
        preset=preset,
        top_k=parse_top_k(top_k),
        max_tool_calls=max_tool_calls,
        trace_path=trace,
        frames=frames,
        temperature=temperature,
        seed=seed,
        show_scores=False if hide_scores else None,
        time_mode=time_mode,
        segment_frames=segment_frames,
        image_max_side=image_max_side,
        max_position_offset=max_position_offset,
    ).check()
    grid, start = _navigation_inputs(memory, from_, robot_radius) if navigate else (None, None)
    img = read_image(image) if image is not None else None
    assert memory is not None  # resolve_server asked for one of the two
    with ravenmem.open(memory) as mem:
        plan = None
        if grid is not None:
            from ravenmem.nav.goals import goal_for

            def plan(ans: Any, allow: bool) -> Any:
                return goal_for(
                    ans, mem, start, robot_radius=robot_radius, grid=grid, allow_unsupported=allow
                )

        result = ask(mem, AskRequest(question, opts, img, plan, allow_unsupported))
        ans = result.answer
        if sheet is not None:
            from ravenmem.viz.sheet import answer_sheet

            answer_sheet(mem, ans.model_dump(mode="json"), sheet)
        data = ans.model_dump(mode="json")
        # only pictures inside the memory folder are named (a stored path is never shown as is)
        files = {r.id: mem.image_file(r) for r in mem.stored([e.id for e in ans.evidence])}
        for ev in data["evidence"]:
            f = files.get(ev["id"])
            ev["image_file"] = str(f) if f else None
        if result.navigation is not None:
            data["navigation"] = result.navigation
    if sheet is not None:
        data["sheet"] = str(sheet)
    _output(data, json_out, result.refusal, result.exit_code)


def _navigation_inputs(
    memory: Path | None, from_: str | None, robot_radius: float | None
) -> tuple[Any, tuple[float, float] | None]:
    """The memory's map and the start, checked before the question costs a model call."""
    from ravenmem.errors import InputError
    from ravenmem.nav.grid import OccupancyGrid

    from .nav import parse_start

    assert memory is not None
    grid = OccupancyGrid.load(memory)  # no map: one line naming how to build one
    start = parse_start(from_)
    if robot_radius is not None and not (math.isfinite(robot_radius) and robot_radius >= 0):
        raise InputError(f"--robot-radius: expected a finite radius >= 0 in metres, got {robot_radius}")
    return grid, start


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
    sys.stdout.write(json.dumps(nav["pose_stamped"]) + "\n")


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
