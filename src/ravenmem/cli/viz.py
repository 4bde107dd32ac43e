"""`ravenmem view`: a memory as a rerun recording (trajectory, keyframes, query hits)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path
from typing import Annotated

import typer

from ._console import esc, out_console
from .options import COUNT, OUTPUT, Force, K, MemoryOpt


def default_out(memory: Path) -> Path:
    """Next to the memory folder: robot.mem -> robot.rrd (robot -> robot.rrd)."""
    m = Path(memory)
    return m.with_suffix(".rrd") if m.suffix else m.with_name(m.name + ".rrd")


def view(
    memory: MemoryOpt,
    out: Annotated[
        Path | None, OUTPUT, typer.Option(help="the .rrd file to write (default: next to the memory)")
    ] = None,
    query: Annotated[str | None, typer.Option(help="a text query whose hits are marked")] = None,
    k: Annotated[int, K, typer.Option("-k", "--k", help="hits of the query")] = 10,
    max_images: Annotated[
        int, COUNT, typer.Option(help="at most this many keyframe pictures (evenly spread)")
    ] = 5000,
    camera_axes: Annotated[
        str,
        typer.Option(help="flu: poses of a robot (x forward, z up); rdf: of an optical frame (z forward)"),
    ] = "flu",
    spawn: Annotated[bool, typer.Option("--spawn", help="then open the file in the rerun viewer")] = False,
    force: Force = False,
    json_out: Annotated[bool, typer.Option("--json", help="machine-readable output")] = False,
) -> None:
    """Write a rerun recording of a memory: trajectory, keyframes with poses, and a query's hits."""
    import json

    import ravenmem
    from ravenmem.errors import require
    from ravenmem.memory.protocol import check_k

    require("rerun", "view")
    from ravenmem.viz.rerun import record

    k = check_k(k)
    target = out if out is not None else default_out(memory)
    with ravenmem.open(memory) as mem:
        hits = mem.search_text(query, k=k) if query is not None else []
        summary = record(mem, target, hits=hits, query=query, max_images=max_images, camera_axes=camera_axes)
    data = {
        "out": summary.out,
        "memories": summary.memories,
        "images": summary.images,
        "hits": summary.hits,
        "entities": summary.entities,
    }
    if json_out:
        sys.stdout.write(json.dumps(data, indent=2) + "\n")
    else:
        out_console().print(
            f"wrote {esc(str(target))}: {summary.memories} memories, {summary.images} pictures"
            + (f", {summary.hits} hits of {esc(repr(query))}" if query is not None else ""),
            highlight=False,
        )
    if spawn:
        subprocess.Popen([sys.executable, "-m", "rerun", str(target)])  # the viewer outlives this command


def register(app: typer.Typer) -> None:
    """Add `view` to the ravenmem command."""
    app.command("view")(view)
