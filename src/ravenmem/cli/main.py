"""The `ravenmem` command: a thin layer over the Python API.

Exit codes: 0 success; 1 a command that ran but failed (a FAILED `ask`); 2 bad input, i.e. a
`RavenmemError` or a usage error (unknown option or command, a missing `--memory`), printed as
one `error: ...` line on stderr without a traceback. Every command has `--json`.
Other areas (agent, nav, eval) add their commands through a `register(app)` in their module.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import sys
from pathlib import Path
from typing import Annotated, Any

import typer
from rich.table import Table
from typer import _click as click
from typer.core import TyperCommand, TyperGroup

from ..errors import InputError, RavenmemError
from ..fsio import disk_full, size_text
from ..threads import share_cores
from ..timeparse import fmt_time
from ..tools import TextArgs
from ._console import esc, out_console, print_error, print_warning
from .commands import COMMANDS
from .options import (
    BATCH,
    DEPTH_SCALE,
    MEMORY_ID,
    NAME,
    PICTURE,
    RATE,
    SECONDS,
    STRIDE,
    THUMB_SIZE,
    Force,
    MemoryOpt,
    MemoryOrServerOpt,
    check_commands,
)
from .options import DISTANCE as DISTANCE_KIND
from .options import K as K_KIND

DIVERSE_HELP = TextArgs.model_fields["diverse"].description  # the tools table says what it does

os.environ.setdefault("HF_HUB_DISABLE_PROGRESS_BARS", "1")  # model-loading bars are noise in a CLI
os.environ.setdefault("TRANSFORMERS_VERBOSITY", "error")
# Downloads are allowed (`--embedder hf:openai/clip-vit-base-patch32` fetches the model once);
# set HF_HUB_OFFLINE=1 yourself to forbid them.


class LazyGroup(TyperGroup):
    """The root command: the other modules' commands (`cli.commands.COMMANDS`) are imported
    when one of them runs or shows its help, not on every start; `ravenmem --help` lists
    them from the table. Help, errors and suggestions are those of the eager command tree."""

    def _load(self, module: str) -> None:
        sub = _extension(module)
        for info in sub.registered_commands:
            cmd = typer.main.get_command_from_info(
                info,
                pretty_exceptions_short=root.pretty_exceptions_short,
                rich_markup_mode=root.rich_markup_mode,
            )
            self.commands[cmd.name or ""] = cmd
        for group in sub.registered_groups:
            grp = typer.main.get_group_from_info(
                group,
                pretty_exceptions_short=root.pretty_exceptions_short,
                rich_markup_mode=root.rich_markup_mode,
                suggest_commands=self.suggest_commands,
            )
            self.commands[grp.name or ""] = grp

    def list_commands(self, ctx: click.Context) -> list[str]:
        own = [n for n in self.commands if n not in COMMANDS]
        return own + list(COMMANDS)

    def get_command(self, ctx: click.Context, cmd_name: str) -> click.Command | None:
        if cmd_name not in self.commands and cmd_name in COMMANDS:
            self._load(COMMANDS[cmd_name][0])
        return self.commands.get(cmd_name)

    def resolve_command(
        self, ctx: click.Context, args: list[str]
    ) -> tuple[str | None, click.Command | None, list[str]]:
        if args and args[0] not in self.commands and args[0] not in COMMANDS:
            for module in dict.fromkeys(m for m, _ in COMMANDS.values()):  # "did you mean" sees all
                if not any(n in self.commands for n, (m, _) in COMMANDS.items() if m == module):
                    self._load(module)
        return super().resolve_command(ctx, args)

    def format_commands(self, ctx: click.Context, formatter: click.HelpFormatter) -> None:
        """The command list of `ravenmem --help`: commands not imported yet by their table entry."""
        for name, (_, text) in COMMANDS.items():
            if name not in self.commands:
                self.commands[name] = _Listed(name, help=text)
        try:
            super().format_commands(ctx, formatter)
        finally:
            for name in [n for n, c in self.commands.items() if isinstance(c, _Listed)]:
                del self.commands[name]


class _Listed(TyperCommand):
    """A command of the table while `ravenmem --help` lists it (its help, nothing to run)."""


PROG = "ravenmem"
root = typer.Typer(
    cls=LazyGroup,
    add_completion=False,
    no_args_is_help=True,
    help="ravenmem: a long-term visual memory for robots.",
    # click's plain help: flags without a "<bool>" column, text wrapped with a hanging indent
    # (the rich panels squeezed help into a narrow column); -h as well as --help
    rich_markup_mode=None,
    context_settings={"help_option_names": ["-h", "--help"], "max_content_width": 100},
)
console = out_console()
JsonOpt = Annotated[bool, typer.Option("--json", help="machine-readable output")]
ServerOpt = Annotated[
    str | None, typer.Option("--server", help="URL of a running `ravenmem serve` (or RAVENMEM_SERVER)")
]


def short_path(p: str | None) -> str:
    """Paths relative to the working directory when under it: tables stay readable."""
    if not p or "://" in p:  # a URL (results from --server) is shown as it is
        return p or ""
    try:
        return os.path.relpath(p) if not os.path.relpath(p).startswith("..") else p
    except ValueError:
        return p


def print_json(obj: Any) -> None:
    sys.stdout.write(json.dumps(obj, indent=2, default=str) + "\n")


def parse_floats(text: str, n: tuple[int, ...], what: str) -> list[float]:
    """`"1.3,0.6"` -> [1.3, 0.6]: n finite numbers (nan and inf are refused)."""
    expected = f"{what}: expected {' or '.join(map(str, n))} comma-separated finite numbers, got {text!r}"
    try:
        vals = [float(v) for v in text.replace(" ", "").split(",")]
    except ValueError:
        raise InputError(expected) from None
    if len(vals) not in n or not all(math.isfinite(v) for v in vals):
        raise InputError(expected)
    return vals


def _version(value: bool) -> None:
    if value:
        from .. import __version__

        sys.stdout.write(f"{PROG} {__version__}\n")
        raise typer.Exit(0)


@root.callback()
def _root(
    version: Annotated[
        bool,
        typer.Option("--version", help="print the version and exit", callback=_version, is_eager=True),
    ] = False,
) -> None:
    """ravenmem: a long-term visual memory for robots."""


KEYFRAMES_HELP = (
    "keyframe rules: 'default' (when left out: moved 0.5 m or turned 15 deg or 5 s passed, "
    "then cosine <= 0.97 to the last keyframe), 'all' (every frame), only the rules named "
    "('fps=2,min_rotation=10deg'), or 'default,max_similarity=0.9'"
)
CAMERA_FRAME_HELP = (
    "image folders: the poses are of a 'body' (x forward, z up; default) or of the "
    "camera's 'optical' frame (x right, y down, z forward, as SLAM systems write them)"
)
MAP_ID_HELP = (
    "the map the poses are in (default: one per recording); a memory in another map "
    "is refused (see `ravenmem align`)"
)


@root.command()
def ingest(
    source: Annotated[
        str,
        typer.Argument(metavar="SOURCE", help="video file, TUM folder, image folder, ROS 1/2 bag or MCAP"),
    ],
    memory: MemoryOpt,
    format: Annotated[
        str | None, typer.Option(help="tum | video | folder | rosbag (default: detect)")
    ] = None,
    poses: Annotated[
        Path | None, typer.Option(help="pose track: CSV t,x,y,z[,yaw|,qx,qy,qz,qw] or TUM")
    ] = None,
    image_topic: Annotated[str | None, typer.Option(help="bag image topic")] = None,
    pose_topic: Annotated[
        str | None, typer.Option(help="bag pose topic (Odometry, PoseStamped or /tf)")
    ] = None,
    embedder: Annotated[
        str, typer.Option(help="offline | open_clip:MODEL/TAG | hf:NAME_OR_PATH")
    ] = "offline",
    store: Annotated[str | None, typer.Option(help="store URI for a new memory (default: embedded)")] = None,
    keyframes: Annotated[str | None, NAME, typer.Option(help=KEYFRAMES_HELP)] = None,
    stride: Annotated[
        int | None, STRIDE, typer.Option(help="keep every Nth frame (alone: instead of the default rules)")
    ] = None,
    fps: Annotated[
        float | None,
        RATE,
        typer.Option(help="at most this many keyframes/s (alone: instead of the default rules)"),
    ] = None,
    ocr: Annotated[bool, typer.Option(help="read text in keyframes (slower)")] = True,
    thumb_size: Annotated[int, THUMB_SIZE, typer.Option(help="thumbnail longer side in px (0 = off)")] = 320,
    batch_size: Annotated[int, BATCH, typer.Option(help="frames embedded per batch")] = 16,
    depth: Annotated[Path | None, typer.Option(help="image folders: the matching depth images")] = None,
    depth_topic: Annotated[str | None, typer.Option(help="bag depth topic (16UC1 mm / 32FC1 m)")] = None,
    depth_scale: Annotated[
        float | None,
        DEPTH_SCALE,
        typer.Option(help="image folders: 16-bit depth units per metre (default 1000 = mm)"),
    ] = None,
    camera_frame: Annotated[str | None, typer.Option(help=CAMERA_FRAME_HELP)] = None,
    intrinsics: Annotated[
        str | None, typer.Option(help="depth camera: fr1 | fr2 | fr3 | kinect | fx,fy,cx,cy")
    ] = None,
    build_map: Annotated[bool, typer.Option("--map/--no-map", help="build the map from depth frames")] = True,
    map_id: Annotated[str | None, NAME, typer.Option(help=MAP_ID_HELP)] = None,
    tf_parent: Annotated[
        str | None, typer.Option(help="bags with /tf: the poses' parent frame (default map, odom or world)")
    ] = None,
    tf_child: Annotated[
        str | None, typer.Option(help="bags with /tf: the posed frame (default base_link)")
    ] = None,
    time_source: Annotated[
        str | None, typer.Option(help="bags: header (header.stamp) or receive (when the bag got it)")
    ] = None,
    pose_match: Annotated[
        str | None, typer.Option(help="interpolate between poses, or the nearest within --max-gap")
    ] = None,
    max_gap: Annotated[
        float | None, SECONDS, typer.Option(help="seconds a frame may be from its pose(s)")
    ] = None,
    wait: Annotated[
        bool, typer.Option("--wait", help="wait while another process writes this memory")
    ] = False,
    json_out: JsonOpt = False,
) -> None:
    """Build (or extend) a memory from a recording, and its map from frames with depth. Frames
    already in it are skipped, so running the same command again after an interruption resumes
    where it stopped."""
    import ravenmem
    from ravenmem.ingest.identity import derived_map_id
    from ravenmem.ingest.pipeline import ALREADY
    from ravenmem.ingest.pipeline import ingest as run_ingest
    from ravenmem.ingest.sources import open_source
    from ravenmem.memory.folder import MANIFEST

    given = dict(locals())  # (taken here: a comprehension has locals of its own)
    opened = {k: given[k] for k in SOURCE_OPTIONS if given[k] is not None}
    cfg = _keyframe_rules(keyframes, stride, fps)
    src = open_source(source, format, **opened)
    derived, frame_id = derived_map_id(src)
    mapper = _mapper(memory, src, intrinsics) if build_map else None
    existed = (memory / MANIFEST).is_file()
    mem = ravenmem.create(
        memory, embedder=embedder, store=store, thumb_size=thumb_size, ocr=ocr, exist_ok=True, wait=wait
    )
    with mem, mem.undo_create_on_error():  # a failed first ingest leaves no folder behind
        note = mem.claim_map(
            map_id or derived, frame_id, given=map_id is not None, what=f"recording {source}"
        )
        if note and not json_out:
            print_warning(note)
        rep = run_ingest(src, mem, keyframes=cfg, batch_size=batch_size, wait=wait, mapper=mapper)
        total = mem.count()
        size = mem.info()
        if rep.kept == 0 and not rep.skipped.get(ALREADY):
            # nothing new and nothing already stored: report why, then fail (exit 2); a memory
            # this command created is removed again rather than left behind empty
            _print_ingest(rep, total, size, cfg, mapper, memory, json_out)
            gone = " (the new memory was not kept)" if total == 0 and not existed else ""
            raise InputError(f"no frame of {source} was kept: nothing was added to {memory}{gone}")
    with ravenmem.open(memory) as done:  # sizes at rest (WAL checkpointed, caches saved), as `info` gives
        size = done.info()
    _print_ingest(rep, total, size, cfg, mapper, memory, json_out)


# the options of `ingest` that go to the recording's source (`ingest.sources.open_source`)
SOURCE_OPTIONS = (
    "poses",
    "image_topic",
    "pose_topic",
    "depth",
    "depth_topic",
    "depth_scale",
    "camera_frame",
    "tf_parent",
    "tf_child",
    "time_source",
    "pose_match",
    "max_gap",
)


def _keyframe_rules(keyframes: str | None, stride: int | None, fps: float | None) -> Any:
    """The keyframe rules of `--keyframes`, `--stride` and `--fps`."""
    from ravenmem.ingest.keyframes import KeyframeConfig

    if keyframes is not None:
        cfg = KeyframeConfig.from_spec(keyframes)
    else:  # `--stride 5` alone means every 5th frame, not the default rules thinned further
        cfg = KeyframeConfig.only() if stride is not None or fps is not None else KeyframeConfig()
    # replace() checks the rules again (a stride of 0 or a NaN rate is a one-line error)
    return dataclasses.replace(
        cfg, stride=cfg.stride if stride is None else stride, fps=cfg.fps if fps is None else fps
    )


def _print_ingest(
    rep: Any, total: int, size: dict[str, Any], cfg: Any, mapper: Any, memory: Path, json_out: bool
) -> None:
    """The ingest report: JSON, or a summary line with the skip reasons, the map and the ratio."""
    from ravenmem.ingest.keyframes import describe

    for w in rep.warnings:
        print_warning(w)
    out = rep.as_dict() | {
        "memory": str(memory),
        "memories_total": total,
        "keyframes": describe(cfg),
        "compression_vs_raw": size["compression_vs_raw"],
        "compression_vs_raw_with_thumbs": size["compression_vs_raw_with_thumbs"],
    }
    if mapper is not None and (mapper.stats.mapped or mapper.stats.skipped or mapper.note):
        out["map"] = mapper.summary()
    if json_out:
        print_json(out)
        return
    ratio = f", 1 in {rep.keyframe_ratio:.1f}" if rep.keyframe_ratio else ""
    console.print(
        f"[bold]{esc(rep.source)}[/]: {rep.frames_seen} frames seen, {rep.kept} kept{ratio} "
        f"({rep.keyframes_per_s:.1f} keyframes/s, {rep.seconds:.1f} s); memory now holds {total}"
    )
    for reason, n in sorted(rep.skipped.items()):
        console.print(f"  skipped {n}: {esc(reason)}")
    if "map" in out:
        m = out["map"]
        cells = (
            f", {m['free']} free / {m['occupied']} occupied cells of {m['cell_size_m']} m"
            if "free" in m
            else ""
        )
        why = "; ".join([f"{n} {r}" for r, n in m["skipped"].items()] + ([m["note"]] if "note" in m else []))
        console.print(
            f"  map: {m['frames_mapped']} depth frames mapped{cells}" + (f" ({esc(why)})" if why else "")
        )
    console.print(f"  keyframe rules: {describe(cfg)}")
    if size["compression_vs_raw"]:
        console.print(
            f"  memory: {size['compression_vs_raw']:,.0f}x smaller than the raw decoded video "
            f"({size['compression_vs_raw_with_thumbs']:,.0f}x with thumbnails), all ingests together"
        )


def _mapper(memory: Path, src: Any, intrinsics: str | None) -> Any:
    """The memory's map builder, with the camera from --intrinsics or the source."""
    from ravenmem.ingest.depth import parse_intrinsics
    from ravenmem.nav.mapping import MapBuilder

    intr = parse_intrinsics(intrinsics) if intrinsics else getattr(src, "intrinsics", None)
    return MapBuilder(memory, intr, getattr(src, "camera_extrinsic", None))


@root.command()
def search(
    memory: MemoryOrServerOpt = None,
    text: Annotated[str | None, typer.Argument(metavar="TEXT", help="text query")] = None,
    image: Annotated[Path | None, typer.Option(help="query image file")] = None,
    like: Annotated[
        int | None, MEMORY_ID, typer.Option("--like", help="memory id: more views like this memory")
    ] = None,
    time: Annotated[str | None, typer.Option("--time", help="K memories forward from this time")] = None,
    position: Annotated[str | None, typer.Option(help="x,y or x,y,z: spatially nearest memories")] = None,
    k: Annotated[int, K_KIND, typer.Option("-k", "--k", help="how many results")] = 5,
    after: Annotated[str | None, typer.Option(help="only memories at or after this time")] = None,
    before: Annotated[str | None, typer.Option(help="only memories at or before this time")] = None,
    near: Annotated[str | None, typer.Option(help="only memories within x,y,r (metres)")] = None,
    radius: Annotated[
        float | None, DISTANCE_KIND, typer.Option(help="with --position: max distance (m)")
    ] = None,
    server: ServerOpt = None,
    diverse: Annotated[
        bool, typer.Option("--diverse/--no-diverse", help=f"text/image: {DIVERSE_HELP}")
    ] = True,
    latest: Annotated[
        bool,
        typer.Option(
            "--latest",
            help="text/image: where is it now? The latest sighting per place, newest first, with "
            "a verdict: still there, not revisited, moved or gone (-k counts places)",
        ),
    ] = False,
    sheet: Annotated[
        Path | None, PICTURE, typer.Option(help="also draw the hits as a contact sheet (PNG) here")
    ] = None,
    force: Force = False,
    json_out: JsonOpt = False,
) -> None:
    """Search a memory with one of the four tools: text, --image/--like, --time or --position."""
    from ravenmem.runtime.service import tool_args
    from ravenmem.tools import get_tool

    from .source import open_source
    from .source import sheet as draw_sheet

    given = {"text": text, "image": image if image is not None else like, "time": time, "position": position}
    modes = [m for m, v in given.items() if v is not None]
    if len(modes) != 1 or (image is not None and like is not None):
        raise InputError("give exactly one of: a text query, --image, --like, --time or --position")
    mode = modes[0]  # k: checked by its option kind here, by the tool where it runs
    if near and mode not in ("text", "image"):
        raise InputError(f"--near applies to text and image searches only, not to --{mode}")
    near_xyr = parse_floats(near, (3,), "--near") if near else None
    if radius is not None and mode != "position":
        raise InputError("--radius applies to --position only; use --near x,y,r with the other tools")
    if (latest or not diverse) and mode not in ("text", "image"):
        flag = "--latest" if latest else "--no-diverse"
        raise InputError(f"{flag} applies to text and image searches only, not to --{mode}")
    if mode == "image":
        args: dict[str, Any] = {"after": after, "before": before, "near": near_xyr, "memory_id": like}
    else:
        query = {"text": text, "time": time, "position": position}[mode]
        args = tool_args(mode, query, "--position", after, before, near_xyr, radius)
    if mode in ("text", "image"):
        args |= {"diverse": diverse} | ({"latest": True} if latest else {})
    tool = get_tool(mode)
    call = tool.validate(args)
    what = f"{mode} search: " + {
        "text": f'"{text}"',
        "image": f"like memory {like}" if like is not None else str(image),
    }.get(mode, str(given[mode]))
    with open_source(memory, server) as src:
        rows = src.search(tool, call, k, image)
        if sheet is not None:
            draw_sheet(
                src, rows, sheet, [what, f"{len(rows)} hit(s), {tool.order_for(call)}  |  {src.where}"]
            )
    if json_out:
        print_json(
            {"mode": mode, "tool": tool.name, "results": rows} | ({"sheet": str(sheet)} if sheet else {})
        )
        return
    _render_hits(rows, tool, call, mode, latest)
    if sheet is not None:
        console.print(f"contact sheet: {esc(str(sheet))}", highlight=False)


def _render_hits(rows: list[dict[str, Any]], tool: Any, call: Any, mode: str, latest: bool) -> None:
    """The hits as a table (and, with --latest, where the thing is now)."""
    table = Table(title=f"{mode} search: {len(rows)} result(s), {tool.order_for(call)}")
    metric = "dist m" if tool.metric == "distance" else "score"
    # the id is what --like ID, forget --ids and the --latest notes ("last m19") name
    cols = ["rank", "id", metric, "time (UTC)", "+s", "x m", "y m", "z m", "yaw deg", "image"]
    for col in cols + (["change"] if latest else []):
        table.add_column(col, justify="right" if col not in ("time (UTC)", "image", "change") else "left")
    for r in rows:
        val = r["distance"] if tool.metric == "distance" else r["score"]
        cells = [
            str(r["rank"]),
            str(r["id"]),
            "" if val is None else f"{val:.3f}",
            r["time"],
            f"{r['offset_s']:.2f}",
            f"{r['x']:.2f}",
            f"{r['y']:.2f}",
            f"{r['z']:.2f}",
            f"{r['yaw_deg']:.0f}",
            esc(short_path(r["image"])),
        ]
        if latest:
            ch = r.get("change", {})
            verdict = ch.get("verdict", "") if ch.get("role") == "sighting" else "view without it"
            cells.append(f"place {ch.get('place')}: {esc(verdict)}")
        table.add_row(*cells, style="dim" if r.get("supported") is False else None)
    if latest:
        first = rows[0].get("change", {}) if rows else {}
        status = first.get("status") or "not seen"
        note = first.get("status_note")
        console.print(f"status: {esc(status)}" + (f" ({esc(note)})" if note else ""), highlight=False)
        for r in rows:
            ch = r.get("change", {})
            if ch.get("role") == "sighting":
                console.print(f"  {esc(ch.get('text', ''))}", highlight=False)
    console.print(table)
    if rows and all(r.get("supported") is False for r in rows):
        console.print(
            f'warning: nothing in this memory supports "{esc(str(getattr(call, "query", "")))}": no hit scores above what '
            "things that are not there reach (the rule `ask --offline` declines by); these are only "
            "the least unlike",
            highlight=False,
        )


@root.command()
def info(memory: MemoryOrServerOpt = None, server: ServerOpt = None, json_out: JsonOpt = False) -> None:
    """Counts, time span, extent, embedder, bytes per memory and compression of a memory."""
    from .source import open_source

    with open_source(memory, server) as src:
        data = src.info()
    if json_out:
        print_json(data)
        return
    for label, value in info_lines(data):
        console.print(f"{label:>12}  {esc(value)}", highlight=False)


@root.command("name")
def name_cmd(
    memory: MemoryOpt,
    new: Annotated[
        str | None, typer.Argument(metavar="[NAME]", help="the new display name ('' clears it)")
    ] = None,
    json_out: JsonOpt = False,
) -> None:
    """Show or set the memory's display name (what `info` and the service's page show; the
    folder keeps its own name)."""
    import ravenmem

    if new is None:
        with ravenmem.open(memory) as mem:
            name, own = mem.name, bool(mem.manifest.name)
    else:
        with ravenmem.open(memory, writable=True) as mem:
            mem.set_name(new)
            name, own = mem.name, bool(mem.manifest.name)
    if json_out:
        print_json({"memory": str(memory), "name": name, "set": own})
    else:
        console.print(esc(name) + ("" if own else " (the folder's name: none set)"), highlight=False)


def _plain(value: Any) -> str:
    """Any other value of `info` in words: yes/no, 'key: value' lists, numbers with separators."""
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, float):
        return f"{value:,.2f}"
    if isinstance(value, int):
        return f"{value:,}"
    if isinstance(value, dict):
        return ", ".join(f"{k}: {_plain(v)}" for k, v in value.items()) or "-"
    if isinstance(value, (list, tuple)):
        return ", ".join(_plain(v) for v in value) or "-"
    return "-" if value is None else str(value)


def info_lines(data: dict[str, Any]) -> list[tuple[str, str]]:
    """`ravenmem info` as a person reads it: (label, text) rows; the figures `--json` gives raw.
    Keys this function does not know (a newer service's) are printed in words after the rest."""
    d = dict(data)
    path, name = str(d.pop("path", "")), str(d.pop("name", "") or "")
    rows: list[tuple[str, str]] = [("memory", path)]
    if name and name != Path(path).name:
        rows.append(("name", name))
    n, seen = d.pop("memories", 0) or 0, d.pop("frames_seen", 0) or 0
    ratio = d.pop("keyframe_ratio", None)
    kept = f" (kept from {seen:,} frames seen: 1 in {ratio:.1f})" if seen and ratio else ""
    rows.append(("memories", f"{n:,}{kept}"))
    if "consolidated" in d:
        rows.append(
            (
                "consolidated",
                f"{d.pop('consolidated'):,} merged memories, standing for "
                f"{d.pop('memories_represented', n):,} in all",
            )
        )
    t0, t1, dur = d.pop("t_min", None), d.pop("t_max", None), d.pop("duration_s", None)
    if isinstance(t0, (int, float)) and isinstance(t1, (int, float)):
        span = f" ({dur:,.1f} s)" if isinstance(dur, (int, float)) else ""
        rows.append(("time", f"{fmt_time(t0)} to {fmt_time(t1)}{span}"))
    ext = d.pop("extent", None)
    if ext:
        rows.append(("extent", ", ".join(f"{c} {lo:.2f} .. {hi:.2f} m" for c, (lo, hi) in ext.items())))
    dim = d.pop("dim", None)
    rows.append(("embedder", f"{d.pop('embedder', '')}" + (f" ({dim} dimensions)" if dim else "")))
    rows.append(("store", str(d.pop("store", ""))))
    if "ocr" in d:
        rows.append(("OCR", "on" if d.pop("ocr") else "off"))
    if "thumb_size" in d:
        size = d.pop("thumb_size")
        rows.append(("thumbnails", f"{size} px on the longer side" if size else "off"))
    store_b, thumb_b = d.pop("store_bytes", None), d.pop("thumb_bytes", None)
    per, per_t = d.pop("bytes_per_memory", None), d.pop("bytes_per_memory_with_thumbs", None)
    if store_b is not None:
        text = size_text(store_b) + (f" ({size_text(per)} per memory)" if per else "")
        if thumb_b:
            text += f"; thumbnails {size_text(thumb_b)}" + (
                f" ({size_text(per_t)} per memory with them)" if per_t else ""
            )
        rows.append(("size", text))
    raw, comp = d.pop("raw_video_bytes", None), d.pop("compression_vs_raw", None)
    comp_t = d.pop("compression_vs_raw_with_thumbs", None)
    if comp:
        with_t = f", {comp_t:,.0f}x with thumbnails" if comp_t else ""
        rows.append(
            (
                "compression",
                f"{comp:,.0f}x smaller than the raw decoded video ({size_text(raw or 0)}){with_t}",
            )
        )
    for rep in d.pop("ingests", None) or []:
        skipped = ", ".join(f"{v:,} {k}" for k, v in (rep.get("skipped") or {}).items())
        took = rep.get("seconds")
        rows.append(
            (
                "ingest",
                f"{rep.get('source')}: {rep.get('frames_seen', 0):,} frames seen, {rep.get('kept', 0):,} kept"
                + (f" in {took:,.0f} s" if isinstance(took, (int, float)) else "")
                + (f"; skipped {skipped}" if skipped else ""),
            )
        )
    frame, map_id, anchor = d.pop("frame_id", None), d.pop("map_id", None), d.pop("anchor", None)
    if map_id:
        rows.append(("map", f"{map_id}" + (f" (poses in frame {frame})" if frame else "")))
    if isinstance(anchor, dict):  # `ravenmem align --apply` moved the poses
        origin = anchor.get("from") or {}
        x, y, z, yaw = (list(anchor.get("transform") or []) + [0.0] * 4)[:4]
        rows.append(
            (
                "anchor",
                f"re-anchored from map {origin.get('map_id', '?')}: moved ({x:.2f}, {y:.2f}, {z:.2f}) m, "
                f"turned {math.degrees(yaw):.1f} deg",
            )
        )
    ask = d.pop("ask", None)
    if isinstance(ask, dict):  # a service's: how it answers questions
        text = f"default method {ask.get('default_method')}"
        if ask.get("default_preset"):
            text += f", preset {ask['default_preset']}"
        needs = ", ".join(ask.get("needs_vlm") or [])
        text += (
            "; a VLM is configured"
            if ask.get("vlm")
            else f"; no VLM ({needs} need one)"
            if needs
            else "; no VLM"
        )
        rows.append(("ask", text))
    rows += [(str(k).replace("_", " "), _plain(v)) for k, v in d.items()]
    return rows


def _extension(module: str) -> typer.Typer:
    """The commands `ravenmem.cli.<module>` adds, registered on an app of their own and checked
    by their option models (as every command is: `check_commands`)."""
    sub = typer.Typer()
    # (`__import__`, not `importlib.import_module`: `python -X importtime` lists what it loads)
    __import__(f"ravenmem.cli.{module}", fromlist=["register"]).register(sub)
    check_commands(sub)
    return sub


def every_command() -> typer.Typer:
    """The root app with every module's commands registered on it, as `app` (the command
    reference, tests that walk the tree): imports them all."""
    if not _every:
        for module in dict.fromkeys(m for m, _ in COMMANDS.values()):
            sub = _extension(module)
            root.registered_commands += sub.registered_commands
            root.registered_groups += sub.registered_groups
        _every.append(True)
    return root


_every: list[bool] = []


def __getattr__(name: str) -> Any:
    if name == "app":  # the whole command tree, every module's commands registered
        return every_command()
    raise AttributeError(name)


check_commands(root)  # every command's options, checked once by its option model (cli.options)


def main(argv: list[str] | None = None) -> None:
    """The `ravenmem` entry point: run a command and turn its outcome into an exit code.

    typer runs on its own copy of click (`typer._click`), so its exceptions are caught through
    typer's public classes: every click error (usage errors included) is a `typer.TyperException`;
    `typer.Exit(code)` comes back as the return value in non-standalone mode.
    """
    # the hub library's retry warnings would spread one error over many stderr lines; a user
    # who wants them sets HF_HUB_VERBOSITY (read when huggingface_hub is imported)
    os.environ.setdefault("HF_HUB_VERBOSITY", "error")
    share_cores()  # OpenMP pools that sleep, not spin, on a shared computer (ravenmem.threads)
    for stream in (sys.stdout, sys.stderr):  # text from argv may hold lone surrogates
        reconfigure = getattr(stream, "reconfigure", None)
        if reconfigure is not None:
            reconfigure(errors="backslashreplace")
    try:
        rc = root(args=argv, prog_name=PROG, standalone_mode=False)
    except RavenmemError as e:
        print_error(e)
        sys.exit(2)
    except typer.TyperException as e:
        sys.exit(_usage_error(e))
    except typer.Exit as e:  # raised outside a command (typer returns it from inside one)
        sys.exit(e.exit_code)
    except typer.Abort:
        print_error("aborted")
        sys.exit(1)
    except Exception as e:  # a full disk is the user's to fix: one line, not a traceback
        full = disk_full(e)
        if full is None:
            raise
        print_error(full)
        sys.exit(2)
    sys.exit(rc if isinstance(rc, int) else 0)


def _usage_error(e: typer.TyperException) -> int:
    """One line for a click error (with where to get help); the help page for a bare `ravenmem`."""
    show = getattr(e, "show", None)
    ctx = getattr(e, "ctx", None)
    if type(e).__name__ == "NoArgsIsHelpError" and show is not None:
        show()  # `ravenmem` alone: the help page, as click prints it
        return 2
    hint = f" (see '{ctx.command_path if ctx is not None else PROG} --help')"
    print_error(f"{e.format_message()}{hint}")
    return 2


if __name__ == "__main__":
    main()
