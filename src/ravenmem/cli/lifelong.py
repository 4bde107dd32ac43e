"""`ravenmem forget` and `ravenmem consolidate`: a memory that lives for months stays bounded."""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path
from typing import Annotated, Any

import typer

from ..fsio import size_text
from ._console import esc, out_console
from .options import COUNT, GAP, SIMILARITY, SPAN, MemoryOpt

JsonOpt = Annotated[bool, typer.Option("--json", help="machine-readable output")]
DryRun = Annotated[bool, typer.Option("--dry-run", help="only report what would happen")]
Wait = Annotated[bool, typer.Option("--wait", help="wait while another process writes this memory")]


def _open(memory: Path, dry_run: bool, wait: bool) -> Any:
    import ravenmem

    return ravenmem.open(memory) if dry_run else ravenmem.open(memory, writable=True, wait=wait)


def _print(out: dict[str, Any], json_out: bool, line: str) -> None:
    if json_out:
        sys.stdout.write(json.dumps(out, indent=2, default=str) + "\n")
    else:
        out_console().print(esc(line), highlight=False)


def forget(
    memory: MemoryOpt,
    before: Annotated[str | None, typer.Option(help="memories at or before this time")] = None,
    after: Annotated[str | None, typer.Option(help="memories at or after this time")] = None,
    region: Annotated[str | None, typer.Option(help="memories taken within x,y,r (metres)")] = None,
    ids: Annotated[str | None, typer.Option(help="memory ids, e.g. 3,7,10-12")] = None,
    dry_run: DryRun = False,
    wait: Wait = False,
    json_out: JsonOpt = False,
) -> None:
    """Remove memories for good (index, metadata, thumbnails). Selectors combine: a memory goes
    when it matches every one given. Crash-safe: a kill leaves all of them or none."""
    from ravenmem.cli.main import parse_floats
    from ravenmem.memory.lifelong.forget import parse_ids

    disc = parse_floats(region, (3,), "--region") if region is not None else None
    id_list = parse_ids(ids) if ids is not None else None
    with _open(memory, dry_run, wait) as mem:
        rep = mem.forget(
            before=before,
            after=after,
            region=tuple(disc) if disc else None,
            ids=id_list,
            dry_run=dry_run,
        )
    out = rep.as_dict() | {"memory": str(memory)}
    verb = "would forget" if dry_run else "forgot"
    span = f" from {out['first_time']} to {out['last_time']}" if rep.removed else ""
    unknown = f"; {rep.unknown_ids} of the given ids are not in the memory" if rep.unknown_ids else ""
    used = [f"--{k} {v!r} = {out[f'{k}_time']}" for k, v in (("before", before), ("after", after)) if v]
    line = (
        f"{verb} {rep.removed} memories{span}, {rep.thumbnails} thumbnails, "
        f"{size_text(rep.bytes_freed)} ({size_text(rep.thumbnail_bytes)} of thumbnails); "
        f"{rep.memories_left} left{unknown}"
        + (
            f" ({'; '.join(used)}: resolved against all the memory ever held, so a rerun means the same)"
            if used
            else ""
        )
    )
    _print(out, json_out, line)


def consolidate(
    memory: MemoryOpt,
    budget: Annotated[int | None, COUNT, typer.Option(help="keep at most this many memories")] = None,
    max_similarity: Annotated[
        float | None, SIMILARITY, typer.Option(help="merge neighbours more similar than this cosine")
    ] = None,
    max_distance: Annotated[
        float, SPAN, typer.Option(help="a merged run fits in a box this many metres across (inf: no limit)")
    ] = 1.0,
    max_gap: Annotated[
        float | None, GAP, typer.Option(help="never merge across a gap in time longer than this (s)")
    ] = None,
    dry_run: DryRun = False,
    wait: Wait = False,
    json_out: JsonOpt = False,
) -> None:
    """Merge runs of near-duplicate memories (same place, consecutive in time) into one that
    keeps their time span and count, most similar first, to a budget or a similarity."""
    with _open(memory, dry_run, wait) as mem:
        rep = mem.consolidate(
            budget=budget,
            max_similarity=max_similarity,
            max_distance=max_distance,
            max_gap=max_gap,
            dry_run=dry_run,
        )
    out = rep.as_dict() | {"memory": str(memory)}
    verb = "would merge" if dry_run else "merged"
    low = rep.lowest_similarity
    sim = f" (lowest similarity merged {low:.3f})" if low is not None and math.isfinite(low) else ""
    line = (
        f"{verb} {rep.merged} memories into {rep.groups} representatives{sim}: "
        f"{rep.before} -> {rep.after} memories standing for {rep.represented}; "
        f"{size_text(rep.thumbnail_bytes + rep.store_bytes_est)} freed"
    )
    if rep.budget_met is False:
        line += (
            f"; the budget of {rep.budget} was not reached: no more neighbours of one place "
            f"(--max-distance {rep.max_distance:g} m{'' if max_gap is None else f', --max-gap {max_gap:g} s'})"
        )
    _print(out, json_out, line)


def register(app: typer.Typer) -> None:
    """Add `forget` and `consolidate` to the main `ravenmem` command."""
    app.command("forget")(forget)
    app.command("consolidate")(consolidate)
