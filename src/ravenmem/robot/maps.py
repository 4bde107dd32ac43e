"""Build or refresh a memory's map from the recordings its memories came from.

`ravenmem ingest` maps depth frames as it goes; this is for a memory whose map is missing
(ingested with `--no-map`, or before a camera was known) or should be rebuilt with other
settings. Depth is not kept in a memory, so the recordings are read again: the ones given
(`ravenmem map --from PATH`), else those the map itself lists (the builder records each
recording's path with the time of its last mapped frame). A recording must be one of the
memory's (same source identity as its memories): a map of another place would mislead.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from ..errors import InputError, RavenmemError
from ..ingest.depth import parse_intrinsics
from ..ingest.identity import source_identity
from ..ingest.sources import open_source
from ..memory import Memory
from ..memory.folder import MAP_GRID
from ..nav.grid import MapConfig, OccupancyGrid
from ..nav.mapping import MapBuilder


def mapped_recordings(folder: str | Path) -> list[str]:
    """The recordings (paths) the memory's map was built from, in the order first mapped."""
    try:
        grid = OccupancyGrid.load(folder)
    except InputError:
        return []
    return [str(p) for p in grid.meta.get("sources", {})]


def build_map(
    mem: Memory,
    intrinsics: str | None = None,
    config: MapConfig | None = None,
    rebuild: bool = False,
    recordings: Sequence[str | Path] = (),
    say: Callable[[str], None] | None = None,
) -> tuple[OccupancyGrid, dict[str, Any]]:
    """Replay recordings into the memory's map (only frames not in it yet, unless `rebuild`).
    Returns the map and a report per recording."""
    folder = Path(mem.path)
    paths = [str(p) for p in recordings] or mapped_recordings(folder)
    if not paths:
        raise InputError(
            f"{folder}: no map and no recording to build one from; pass the recording with --from "
            "(a TUM folder with depth.txt, a bag with a depth topic)"
        )
    known = {r.source for r in mem.all_records()}
    report: dict[str, Any] = {"recordings": {}}
    first = True
    for path in paths:
        if not Path(path).exists():
            report["recordings"][path] = "not found"
            continue
        try:
            src = open_source(path)
        except RavenmemError as e:
            report["recordings"][path] = f"cannot open: {e}"
            continue
        if known and source_identity(src) not in known and str(path) not in known:
            raise InputError(
                f"{path} is not a recording of {folder} (its memories come from other recordings)"
            )
        intr = parse_intrinsics(intrinsics) if intrinsics else getattr(src, "intrinsics", None)
        builder = MapBuilder(
            folder, intr, getattr(src, "camera_extrinsic", None), config, rebuild=rebuild and first
        )
        if say is not None:
            say(f"map: reading {path}")
        for f in src:
            if f.depth is not None:
                builder.add(f)
        builder.close()
        first = first and builder.grid is None  # a rebuild starts over once, with the first map made
        report["recordings"][path] = builder.summary()
    if not (folder / MAP_GRID).is_file():
        why = "; ".join(
            f"{p}: {v if isinstance(v, str) else _why(v)}" for p, v in report["recordings"].items()
        )
        raise InputError(
            f"{folder}: no map could be built ({why}); a map needs depth (TUM depth.txt, a bag depth "
            "topic, --depth for image folders) and the camera (--intrinsics)"
        )
    return OccupancyGrid.load(folder), report


def _why(summary: dict[str, Any]) -> str:
    reasons = [f"{n} {r}" for r, n in summary.get("skipped", {}).items()]
    return summary.get("note") or ", ".join(reasons) or "no depth frames"
