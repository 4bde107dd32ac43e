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

MemoryOpt = Annotated[Path, typer.Option("--memory", "-m", help="memory folder")]
BaseUrlOpt = Annotated[
    str | None, typer.Option("--base-url", help="OpenAI-compatible endpoint, e.g. http://localhost:8000/v1")
]
ModelOpt = Annotated[str | None, typer.Option("--model", help="VLM model name")]
KeyOpt = Annotated[
    str | None, typer.Option("--api-key", help="API key (default: RAVENMEM_VLM_API_KEY / OPENAI_API_KEY)")
]
ConfigOpt = Annotated[
    Path | None, typer.Option("--config", help="config file (default ~/.config/ravenmem/config.toml)")
]
TimeoutOpt = Annotated[float | None, typer.Option("--timeout", help="seconds per VLM request")]
RetriesOpt = Annotated[int | None, typer.Option("--max-retries", help="retries on 429/5xx/timeouts")]


def ask(
    question: Annotated[str, typer.Argument(help="the question, e.g. 'Where did I leave the red backpack?'")],
    memory: MemoryOpt,
    image: Annotated[Path | None, typer.Option(help="a query image ('where did I see this?')")] = None,
    offline: Annotated[bool, typer.Option("--offline", help="no VLM: the offline reasoner")] = False,
    method: Annotated[
        str | None,
        typer.Option(help="raven | offline | embedder-only | vlm-only | caption | random (default raven)"),
    ] = None,
    base_url: BaseUrlOpt = None,
    model: ModelOpt = None,
    api_key: KeyOpt = None,
    tool_mode: Annotated[
        str | None, typer.Option(help="auto | native | json (JSON-in-prompt, no function calling)")
    ] = None,
    top_k: Annotated[int, typer.Option(help="memories per tool call")] = 5,
    max_tool_calls: Annotated[int, typer.Option(help="tool calls before the model must answer")] = 3,
    frames: Annotated[int, typer.Option(help="vlm-only: frames sampled over the whole history")] = 16,
    trace: Annotated[
        Path | None, typer.Option(help="save the full request/response trace (JSON) here")
    ] = None,
    timeout: TimeoutOpt = None,
    max_retries: RetriesOpt = None,
    config: ConfigOpt = None,
    json_out: Annotated[bool, typer.Option("--json", help="machine-readable output")] = False,
) -> None:
    """Answer a question from a memory: position, time, yes/no, duration or text, with evidence."""
    import ravenmem
    from ravenmem.agent import VLMConfig, create_method
    from ravenmem.errors import InputError
    from ravenmem.imageio import read_image

    if offline and method not in (None, "offline"):
        raise InputError(f"--offline and --method {method} contradict each other")
    name = "offline" if offline else (method or "raven")
    vlm = None
    if name in ("raven", "vlm-only", "caption"):
        vlm = VLMConfig.resolve(
            config_path=config, base_url=base_url, model=model, api_key=api_key, tool_mode=tool_mode,
            timeout=timeout, max_retries=max_retries,
        )  # fmt: skip
    img = read_image(image) if image is not None else None
    with ravenmem.open(memory) as mem:
        m = create_method(
            name, mem, vlm=vlm, top_k=top_k, max_tool_calls=max_tool_calls, trace_path=trace, frames=frames
        )
        ans = m.ask(question, image=img)
        note = getattr(m, "note", "")
        root = Path(mem.path)
    data = ans.model_dump(mode="json")
    for ev in data["evidence"]:
        p = ev.get("image_path")
        ev["image_file"] = str(root / p) if p and not Path(p).is_absolute() else p
    if json_out:
        if note:
            data["note"] = note
        sys.stdout.write(json.dumps(data, indent=2) + "\n")
    else:
        _render(data, note)
    if ans.failed:
        raise typer.Exit(1)


def _render(a: dict[str, Any], note: str) -> None:
    con = out_console()
    if note:
        con.print(f"[yellow]note:[/] {esc(note)}", highlight=False)
    status = "[red]FAILED[/]" if a["failed"] else ("found" if a["found"] else "[yellow]not found[/]")
    con.print(f"[bold]type:[/] {esc(a['question_type'])}   [bold]method:[/] {esc(a['method'])}   {status}")
    con.print(f"[bold]answer:[/] {esc(a['text'])}", highlight=False)
    if a.get("position"):
        x, y, z = a["position"]
        yaw = f"{math.degrees(a['yaw']):.0f} deg" if a.get("yaw") is not None else "-"
        con.print(f"[bold]x y z yaw:[/] {x:.2f} {y:.2f} {z:.2f} {yaw}   ({esc(a['position_source'])})")
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
        for col in ("id", "time (UTC)", "x", "y", "z", "yaw", "score", "image"):
            table.add_column(col, justify="left" if col in ("time (UTC)", "image") else "right")
        for e in a["evidence"]:
            score = "" if e.get("score") is None else f"{e['score']:.3f}"
            table.add_row(str(e["id"]), fmt_time(e["t"]), f"{e['x']:.2f}", f"{e['y']:.2f}", f"{e['z']:.2f}",
                          f"{math.degrees(e['yaw']):.0f}", score, esc(e.get("image_file") or ""))  # fmt: skip
        con.print(table)
    c = a["cost"]
    con.print(
        f"[bold]tool calls used:[/] {c['tool_calls']}   memories shown {c['memories_shown']}/{c['memories_total']} "
        f"(alpha {c['alpha']:.4f})   images {c['images']}   tokens {c['prompt_tokens']}+{c['completion_tokens']}   "
        f"{c['wall_s']:.2f} s"
    )
    if a.get("reasoning"):
        con.print(f"[dim]reasoning: {esc(a['reasoning'])}[/]", highlight=False)


def caption(
    memory: MemoryOpt,
    base_url: BaseUrlOpt = None,
    model: ModelOpt = None,
    api_key: KeyOpt = None,
    timeout: TimeoutOpt = None,
    max_retries: RetriesOpt = None,
    config: ConfigOpt = None,
    json_out: Annotated[bool, typer.Option("--json", help="machine-readable output")] = False,
) -> None:
    """Caption every memory with a VLM (for the caption baseline); re-running captions only new ones."""
    import ravenmem
    from ravenmem.agent import VLMConfig, caption_memories
    from ravenmem.agent.captions import CAPTION_FILE

    vlm = VLMConfig.resolve(
        config_path=config,
        base_url=base_url,
        model=model,
        api_key=api_key,
        timeout=timeout,
        max_retries=max_retries,
    )
    with ravenmem.open(memory) as mem:
        n = caption_memories(mem, vlm)
        total = mem.count()
    out = {"captioned_now": n, "memories": total, "file": str(Path(memory) / CAPTION_FILE)}
    if json_out:
        sys.stdout.write(json.dumps(out, indent=2) + "\n")
    else:
        Console().print(f"captioned {n} memories ({total} in the memory); captions in {esc(out['file'])}")


def register(app: typer.Typer) -> None:
    """Add `ask` and `caption` to the ravenmem command."""
    app.command("ask")(ask)
    app.command("caption")(caption)
