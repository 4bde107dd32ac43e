"""`ravenmem align`: the transform from one memory's map into another's (estimated from the
places both saw, or given), and re-anchoring the first memory into the second's map with it.
Thin over `ravenmem.nav.align`."""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path
from typing import Annotated

import typer


def align(
    from_: Annotated[Path, typer.Option("--from", help="the memory to move (A)")],
    to: Annotated[Path | None, typer.Option("--to", help="the memory whose map A is put into (B)")] = None,
    transform: Annotated[
        str | None,
        typer.Option(
            help="the transform A -> B instead of estimating it: x,y,z,yaw (metres; yaw in degrees)"
        ),
    ] = None,
    apply: Annotated[
        bool, typer.Option("--apply", help="re-anchor A into B's map (poses and map; nothing re-embedded)")
    ] = False,
    undo: Annotated[
        bool, typer.Option("--undo", help="put A's poses and map back where they were first stored")
    ] = False,
    json_out: Annotated[bool, typer.Option("--json", help="machine-readable output")] = False,
) -> None:
    """Estimate the rigid transform (rotation about z, shift) from memory A's map into memory B's,
    from image matches between them and a RANSAC fit of their poses (refined on their maps), or
    take the one given; with --apply, move A into B's map. Without --apply nothing is written."""
    import ravenmem
    from ravenmem.errors import InputError
    from ravenmem.memory.anchor import Transform
    from ravenmem.nav import align as al

    from .main import parse_floats

    if undo:
        if to is not None or transform is not None or apply:
            raise InputError("--undo takes --from only")
        with ravenmem.open(from_, writable=True) as a:
            done = al.undo(a)
            out = {"undone": True, "memory": str(from_), **done, **a.map_identity()}
        _print(
            out,
            json_out,
            f"{from_}: back in map {out['map_id']!r} ({done['memories']} memories, map {done['map']})",
        )
        return
    if to is None:
        raise InputError("give --to (the memory whose map to align with), or --undo")
    if from_.resolve() == to.resolve():
        raise InputError(f"--from and --to are the same memory ({from_})")
    given = None
    if transform is not None:  # checked before either memory is opened
        x, y, z, yaw_deg = parse_floats(transform, (4,), "--transform")
        try:
            given = Transform(x, y, z, math.radians(yaw_deg))
        except InputError as e:
            raise InputError(f"--transform: {e}") from None
    with ravenmem.open(to) as b, ravenmem.open(from_, writable=apply) as a:
        found = al.Alignment(given, a.map_id, b.map_id, "given") if given is not None else al.estimate(a, b)
        out = {"from": str(from_), "to": str(to), **found.as_dict()}
        if apply:
            out["applied"] = al.apply(a, found.transform, b.map_id, b.frame_id)
            out |= {"map_id": a.map_id, "frame_id": a.frame_id}
    t = found.transform
    line = (
        f"{from_} -> {to}: x {t.x:.3f} m, y {t.y:.3f} m, z {t.z:.3f} m, yaw {math.degrees(t.yaw):.2f} deg ({found.method}"
        + (
            f": {found.inliers} of {found.matches} matched places agree, residual {found.residual_m:.2f} m"
            if found.matches
            else ""
        )
        + (
            f"; maps fitted to {found.map_fit['rms_m']} m"
            if found.map_fit and found.method.endswith("maps")
            else ""
        )
        + ")"
    )
    if apply:
        line += f"\napplied: {out['applied']['memories']} memories moved, map {out['applied']['map']}; {from_} is now in map {out['map_id']!r}"
    _print(out, json_out, line + "".join(f"\nnote: {n}" for n in found.notes))


def _print(out: dict[str, object], json_out: bool, line: str) -> None:
    if json_out:
        sys.stdout.write(json.dumps(out, indent=2, default=str) + "\n")
    else:
        sys.stdout.write(line + "\n")


def register(app: typer.Typer) -> None:
    """Add `align` to the ravenmem command."""
    app.command("align")(align)
