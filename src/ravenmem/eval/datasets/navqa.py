"""NaVQA (ReMEmbR's benchmark over CODa) in the layouts its two releases use, and ours.

Layouts (`navqa:PATH`; PATH is the repository root or its data folder):

    RAVEN release (github.com/princeton-prism/RAVEN; PATH = the repository or its data_vlm/):
      data_vlm/questions/<seq>/human_qa.json   the questions with their answers, per sequence
      data_vlm/navqa/data.csv                  the question table (clock times in UTC-5)
      data_vlm/navqa/<seq>/qa_unfilled.json    the clips (start_time..end_time per question)
      coda_data/<seq>/<unix time>.pkl          frames, at the repository root
    ReMEmbR release (github.com/NVIDIA-AI-IOT/remembr; PATH = the repository, its remembr/ or data/):
      remembr/data/navqa/data.csv              the question table (clock times in UTC-8)
      remembr/data/navqa/<seq>/qa_unfilled.json the clips, about 30 per sequence, one per question
      remembr/data/questions/<seq>/human_qa.json  when its form_question_jsons script was run
      remembr/coda_data/<seq>/<unix time>.pkl  frames, beside data/ (its eval.md: --coda_dir ./coda_data)
    either release's navqa folder itself (data_vlm/navqa, remembr/data/navqa): data.csv and
      <seq>/qa_unfilled.json there, coda_data/ two levels up (the repository or package root)
    ours: PATH/data.csv, PATH/questions/<seq>/human_qa.json (or PATH/<seq>/human_qa.json),
      frames in PATH/coda_data/<seq>/*.pkl or PATH/frames/<seq>/poses.csv (file,t,x,y,z[,qx,qy,qz,qw])

data.csv: UUID, Seq ID, Question, Timestamp with answer (H:MM:SS, or two for a duration), Type
(binary / position / time / text / duration), Text answer, Parsable answer, Question Category
(matched by name, multi-line headers allowed). human_qa.json: {"data": [{id, length_category,
start_time, end_time, question, type, answers: {position | time (minutes before end_time) |
duration (minutes) | text: [...]}}]}. qa_unfilled.json: the same items without question and
answers. A CODa frame pickle holds cam0 (BGR image), position, rotation (quaternion) and
timestamp; it is read with an unpickler that only builds numpy arrays (a tampered file cannot
run code).

Episodes: every clip is an episode with a memory of its own window. With human_qa.json the
answers come from it (as the release scorer reads them). With qa_unfilled.json and data.csv (the
ReMEmbR release as shipped) the answers come from data.csv: positions are the sequence's pose at
the timestamp, times that instant, durations the parsable minutes, yes/no the parsable answer.
With data.csv alone a sequence is one episode.

Clock times: data.csv's timestamps are local clock times, and each release wrote them in its own
zone: the RAVEN release in UTC-5 (its human_qa.json texts say "You started moving at 10:55:32"
for start_time 15:55:32 UTC), ReMEmbR's in UTC-8 (the same instant reads 7:59:00 there and
10:59:00 in RAVEN's). The zone comes from `tz` when given, else from the data (`navqa_zone`:
the one whole-hour offset that puts the truth times inside their clips, which are Unix seconds),
else (no timed row) from the release the layout identifies or the offset human_qa.json's texts
are written in. Every truth time must fall inside its episode's recording (within `MARGIN_S`): one
that does not is a named truth error in the report (with the offsets that would fit), never moved
to the nearest frame. A data.csv naming sequences whose frames are missing loads those present
and says which are missing and how many questions that leaves out.
"""

from __future__ import annotations

import csv
import io
import json
import pickle
import re
from collections.abc import Callable
from dataclasses import dataclass, field
from datetime import datetime, timedelta, timezone, tzinfo
from pathlib import Path
from typing import Any, cast

import numpy as np

from ...errors import InputError
from ...fsio import read_text
from ...ingest.poses import read_pose_table
from ...types import Pose
from ..types import Episode, EvalType, Question, Truth, horizon_of
from . import DATASETS
from .frames import FrameRef, RefSource, natural_key
from .navqa_zone import (
    MARGIN_S,
    Inferred,
    Sample,
    clock_instant,
    clock_times,
    infer_zone,
    offset_zone,
    parse_zone,
    zone_label,
)

POS_THRESHOLD = 15.0  # metres, NaVQA's position criterion (the paper's accuracy conversion)
TYPES = ("binary", "position", "time", "text", "duration")
TIMED = ("position", "time", "duration")  # truths that are clock times (checked against the recording)
_COLS = {
    "category": "category",
    "uuid": "uuid",
    "seq id": "seq",
    "timestamp": "stamp",
    "type": "type",
    "text answer": "text",
    "parsable": "parsable",
    "question": "question",
}  # first match wins, in order
_STARTED = re.compile(r"You started moving at (\d{4}-\d{2}-\d{2} \d{1,2}:\d{2}:\d{2})")


@dataclass(frozen=True)
class Release:
    """A published NaVQA release and the zone its data.csv clock times are written in."""

    name: str
    offset_h: int
    about: str

    @property
    def zone(self) -> tzinfo:
        return timezone(timedelta(hours=self.offset_h))


RELEASES = {
    "raven": Release("raven", -5, "the RAVEN release (its human_qa.json texts are UTC-5)"),
    "remembr": Release("remembr", -8, "the ReMEmbR release (written on a UTC-8 clock)"),
}


@dataclass
class Layout:
    """Where one NaVQA copy keeps its files, and which release it is ("" when unknown)."""

    release: str
    data: Path
    frame_roots: list[Path]
    what: str
    navqa: Path | None = None  # the folder of data.csv and <seq>/qa_unfilled.json (default data/navqa)

    @property
    def clips_dir(self) -> Path:
        return self.navqa or self.data / "navqa"

    @property
    def csv(self) -> Path | None:
        for cand in (self.clips_dir / "data.csv", self.data / "data.csv"):
            if cand.exists():
                return cand
        return None

    def human_qa(self, seq: str) -> Path | None:
        for cand in (
            self.data / "questions" / seq / "human_qa.json",
            self.data / seq / "human_qa.json",
            self.data / "human_qa" / f"{seq}.json",
        ):
            if cand.exists():
                return cand
        return None

    def clips(self, seq: str) -> Path | None:
        cand = self.clips_dir / seq / "qa_unfilled.json"
        return cand if cand.exists() else None

    def sequences(self) -> set[str]:
        found = {p.parent.name for p in self.data.glob("questions/*/human_qa.json")}
        found |= {p.parent.name for p in self.data.glob("*/human_qa.json")}
        found |= {p.parent.name for p in self.clips_dir.glob("*/qa_unfilled.json")}
        return found


def _release_of(repo: Path) -> str:
    if (repo / "data_vlm").is_dir() or (repo / "raven").is_dir() or (repo / "raven_qa_run.py").exists():
        return "raven"
    if repo.name == "remembr" or (repo / "remembr" / "data").is_dir():
        return "remembr"
    return ""


def find_layout(root: Path) -> Layout:
    """Which layout (and release) a NaVQA path is (see the module docstring)."""
    if (root / "data_vlm").is_dir():
        return Layout("raven", root / "data_vlm", [root], "RAVEN repository (data_vlm/)")
    if root.name == "data_vlm":
        return Layout("raven", root, [root.parent, root], "RAVEN repository's data_vlm/")
    if (root / "remembr" / "data" / "navqa").is_dir():
        pkg = root / "remembr"
        return Layout("remembr", pkg / "data", [pkg, root], "ReMEmbR repository (remembr/data/)")
    if (root / "data" / "navqa").is_dir():
        rel = _release_of(root)
        return Layout(rel, root / "data", [root], f"{RELEASES[rel].name if rel else 'a'} repository (data/)")
    if (root / "navqa").is_dir():
        rel = _release_of(root.parent)
        return Layout(rel, root, [root.parent, root], f"a repository's data folder ({root.name}/)")
    if (root / "data.csv").exists() and any(root.glob("*/qa_unfilled.json")):
        # the navqa folder itself (data/navqa or data_vlm/navqa): the data folder is its parent
        # and the frames sit beside that (coda_data/ at the repository or package root)
        data, top = root.parent, root.parent.parent
        rel = "raven" if data.name == "data_vlm" else _release_of(top)
        return Layout(rel, data, [top, data, root], f"a NaVQA folder ({data.name}/{root.name}/)", navqa=root)
    return Layout("", root, [root], "flat (data.csv, questions/<seq>/human_qa.json)")


class _NumpyOnly(pickle.Unpickler):
    ALLOWED = {
        ("numpy", "dtype"),
        ("numpy", "ndarray"),
        ("numpy.core.multiarray", "_reconstruct"),
        ("numpy._core.multiarray", "_reconstruct"),
        ("numpy.core.multiarray", "scalar"),
        ("numpy._core.multiarray", "scalar"),
        ("numpy.core.numeric", "_frombuffer"),
        ("numpy._core.numeric", "_frombuffer"),
        ("_codecs", "encode"),
    }

    def find_class(self, module: str, name: str) -> Any:
        if (module, name) not in self.ALLOWED:
            raise pickle.UnpicklingError(f"refusing to load {module}.{name} (only numpy arrays are allowed)")
        return super().find_class(module, name)


def read_coda_pickle(path: Path) -> dict[str, Any]:
    try:
        with open(path, "rb") as f:
            d = _NumpyOnly(f).load()
    except (OSError, pickle.UnpicklingError, EOFError, ValueError) as e:
        raise InputError(f"{path}: cannot read CODa frame pickle ({e})") from e
    if not isinstance(d, dict) or "cam0" not in d or "position" not in d:
        raise InputError(f"{path}: not a CODa frame pickle (needs keys cam0, position)")
    return d


def _coda_image(path: Path) -> np.ndarray:
    img = np.asarray(read_coda_pickle(path)["cam0"])
    if img.ndim == 2:
        img = np.stack([img] * 3, axis=-1)
    return np.ascontiguousarray(img[..., :3][..., ::-1]).astype(np.uint8)  # BGR (cv2) -> RGB


def _loader(path: Path) -> Callable[[], np.ndarray]:
    return lambda: _coda_image(path)


@dataclass
class SeqFrames:
    """One sequence's frames: times, poses and how to load each image."""

    refs: list[FrameRef]

    @property
    def times(self) -> np.ndarray:
        return np.asarray([r.t for r in self.refs])

    @property
    def span(self) -> tuple[float, float]:
        return self.refs[0].t, self.refs[-1].t

    def window(self, t0: float, t1: float) -> list[FrameRef]:
        return [r for r in self.refs if t0 <= r.t <= t1]

    def pose_at(self, t: float) -> Pose | None:
        """The pose of the frame nearest in time to t; None when t is outside the sequence
        (beyond MARGIN_S): a truth there has no position, it is never given the last one."""
        lo, hi = self.span
        if not lo - MARGIN_S <= t <= hi + MARGIN_S:
            return None
        ts = self.times
        i = int(np.clip(np.searchsorted(ts, t), 0, len(ts) - 1))
        if i > 0 and abs(ts[i - 1] - t) < abs(ts[i] - t):
            i -= 1
        return self.refs[i].pose


def frames_folder(roots: list[Path], seq: str) -> Path | None:
    """Where a sequence's frames are: frames/<seq>/poses.csv or coda_data/<seq>/*.pkl."""
    for root in roots:
        if (root / "frames" / seq / "poses.csv").exists():
            return root / "frames" / seq
        pdir = root / "coda_data" / seq
        if pdir.is_dir() and any(pdir.glob("*.pkl")):
            return pdir
    return None


def load_frames(folder: Path) -> SeqFrames:
    """A sequence's frames from its frames/<seq>/poses.csv or coda_data/<seq>/*.pkl folder."""
    csv_path = folder / "poses.csv"
    refs = []
    if csv_path.exists():
        table = read_pose_table(csv_path)
        if table.files is None or table.t is None:
            raise InputError(f"{csv_path}: needs a header with file and t columns")
        for i in range(len(table)):
            q = table.quat[i] if table.quat is not None else None
            x, y, z = (float(v) for v in table.xyz[i])
            pose = Pose.from_quaternion(x, y, z, *map(float, q)) if q is not None else Pose(x, y, z)
            refs.append(FrameRef(t=float(table.t[i]), pose=pose, path=folder / table.files[i]))
    else:
        for p in sorted(folder.glob("*.pkl"), key=lambda p: natural_key(p.stem)):
            d = read_coda_pickle(p)
            pos = [float(v) for v in np.asarray(d["position"]).ravel()[:3]]
            rot = np.asarray(d.get("rotation", []), dtype=float).ravel()
            x, y, z = (pos + [0.0, 0.0, 0.0])[:3]
            pose = Pose.from_quaternion(x, y, z, *map(float, rot[:4])) if rot.size == 4 else Pose(x, y, z)
            refs.append(FrameRef(t=float(d.get("timestamp", p.stem)), pose=pose, load=_loader(p)))
    if not refs:
        raise InputError(f"{folder}: no frames")
    refs.sort(key=lambda r: r.t)
    for i, r in enumerate(refs):
        r.index = i
    return SeqFrames(refs)


def read_data_csv(path: Path) -> list[dict[str, str]]:
    """The NaVQA question table, columns renamed to uuid/seq/question/stamp/type/text/parsable/category."""
    try:
        text = read_text(path, what="question file")
    except OSError as e:
        raise InputError(f"{path}: cannot read ({e.strerror or e})") from e
    reader = csv.reader(io.StringIO(text))
    header = next(reader, None)
    if not header:
        raise InputError(f"{path}: empty file")
    names: list[str | None] = []
    for h in header:
        norm = " ".join(h.lower().split())
        names.append(
            next(
                (v for k, v in _COLS.items() if (k in norm if k == "category" else norm.startswith(k))), None
            )
        )
    for need in ("uuid", "seq", "question", "type"):
        if need not in names:
            raise InputError(f"{path}: no {need!r} column in header {header!r}")
    rows = []
    for n, raw in enumerate(reader, start=2):
        row = {k: raw[i].strip() for i, k in enumerate(names) if k and i < len(raw)}
        if not row.get("question"):
            continue
        row["line"] = str(n)
        rows.append(row)
    return rows


def _hms_times(stamp: str, near: float, zone: tzinfo, where: str) -> list[float]:
    """'7:59:00' or '07:56:38,07:59:00' (clock times in `zone`, on the day nearest `near`) -> Unix s."""
    return [clock_instant(c, zone, near) for c in clock_times(stamp, where)]


def _clock(t: float, zone: tzinfo) -> str:
    return datetime.fromtimestamp(t, zone).strftime("%H:%M:%S")


def fitting_offsets(times: list[float], t0: float, t1: float, offset_h: float) -> list[int]:
    """Whole-hour UTC offsets under which these clock times (read at `offset_h`) would all fall
    inside [t0, t1]: re-reading a clock time at offset o moves it by (offset_h - o) hours."""
    out = []
    for o in range(-12, 15):
        shift = (offset_h - o) * 3600.0
        if all(t0 - MARGIN_S <= t + shift <= t1 + MARGIN_S for t in times):
            out.append(o)
    return out


def check_inside(times: list[float], t0: float, t1: float, zone: tzinfo, read_as_clock: bool) -> str | None:
    """None when every truth time is inside the recording [t0, t1] (within MARGIN_S), else the
    error: which time, how far outside, and (for clock times) which UTC offsets would fit."""
    outside = [t for t in times if not t0 - MARGIN_S <= t <= t1 + MARGIN_S]
    if not outside:
        return None
    t = outside[0]
    side = f"{t - t1:.0f} s after it ends" if t > t1 else f"{t0 - t:.0f} s before it starts"
    msg = (
        f"truth time {_clock(t, zone)} ({zone_label(zone)}) is {side} "
        f"(recording {_clock(t0, zone)}-{_clock(t1, zone)})"
    )
    if read_as_clock:
        off = zone.utcoffset(datetime.fromtimestamp(t, zone))
        offset_h = off.total_seconds() / 3600.0 if off is not None else 0.0
        fits = fitting_offsets(times, t0, t1, offset_h)
        msg += "; " + (
            f"{', '.join(f'UTC{o:+d}' for o in fits)} would fit" if fits else "no whole-hour offset fits"
        )
    return msg


def _horizon(qid: str, length_category: str | None) -> str:
    for h in ("short", "medium", "long"):
        if (length_category or "").lower() == h or f"{h.upper()}_" in qid:
            return h
    return ""


def _yes(text: str) -> bool | None:
    w = text.strip().lower().rstrip(".!")
    return True if w.startswith("yes") else False if w.startswith("no") else None


@dataclass
class _Csv:
    """A data.csv row's truth, read in the episode's zone from the sequence's frames."""

    truth: Truth
    stamps: list[float] = field(default_factory=list)


def _truth_from_csv(
    row: dict[str, str], frames: SeqFrames, window: tuple[float, float], zone: tzinfo, where: str
) -> _Csv:
    qtype = row["type"].lower()
    truth = Truth()
    near = 0.5 * (window[0] + window[1])
    stamps = _hms_times(row["stamp"], near, zone, where) if row.get("stamp") else []
    out = _Csv(truth, stamps if qtype in TIMED else [])
    if qtype == "position" and stamps:
        poses = [frames.pose_at(t) for t in stamps]
        truth.positions = [list(p.xyz) for p in poses if p is not None]
    elif qtype == "time" and stamps:
        truth.times = stamps
    elif qtype == "duration":
        try:
            truth.duration = float(row.get("parsable", "")) * 60.0
        except ValueError:
            if len(stamps) == 2:
                truth.duration = stamps[1] - stamps[0]
    elif qtype == "binary":
        truth.yes = _yes(row.get("parsable", "") or row.get("text", ""))
    if row.get("text"):
        truth.text = [row["text"]]
    return out


def _truth_from_json(item: dict[str, Any]) -> Truth:
    ans = item.get("answers") or {}
    qtype = str(item.get("type", "")).lower()
    truth = Truth(
        text=[str(t) for t in ans.get("text", []) if t] if isinstance(ans.get("text"), list) else []
    )
    pos = ans.get("position")
    if (
        qtype == "position"
        and isinstance(pos, list)
        and len(pos) >= 2
        and all(isinstance(v, (int, float)) for v in pos)
    ):
        truth.positions = [[float(v) for v in pos[:3]] + [0.0] * (3 - len(pos[:3]))]
    if qtype == "time" and isinstance(ans.get("time"), (int, float)):
        truth.times = [float(item["end_time"]) - 60.0 * float(ans["time"])]
    if qtype == "duration" and isinstance(ans.get("duration"), (int, float)):
        truth.duration = 60.0 * float(ans["duration"])
    if qtype == "binary" and truth.text:
        truth.yes = _yes(truth.text[0])
    return truth


def _scorable(qtype: str, t: Truth) -> bool:
    return {
        "position": bool(t.positions),
        "time": bool(t.times),
        "duration": t.duration is not None,
        "binary": t.yes is not None,
        "text": bool(t.text),
    }.get(qtype, False)


def _context(q: str, pose: Pose) -> str:
    return f"You are now at position [{pose.x:.2f}, {pose.y:.2f}, {pose.z:.2f}] (metres, map frame). {q}"


def _read_items(path: Path, what: str) -> list[dict[str, Any]]:
    try:
        items = json.loads(read_text(path, what="question file"))["data"]
    except (OSError, ValueError, KeyError, TypeError) as e:
        raise InputError(f"{path}: not a {what} ({e})") from e
    if not isinstance(items, list):
        raise InputError(f"{path}: 'data' must be a list")
    return items


def text_offset(items: list[dict[str, Any]]) -> int | None:
    """The UTC offset (hours) human_qa.json's texts are written in: 'You started moving at
    <clock time>' beside the item's start_time (Unix s). None when the texts do not say."""
    for item in items:
        m = _STARTED.search(str(item.get("question", "")))
        if m and isinstance(item.get("start_time"), (int, float)):
            local = datetime.strptime(m.group(1), "%Y-%m-%d %H:%M:%S").replace(tzinfo=timezone.utc)
            return round((local.timestamp() - float(item["start_time"])) / 3600.0)
    return None


@dataclass
class _Clip:
    """One question's clip: its window and what the question is, before the episode is made."""

    qid: str
    t0: float
    t1: float
    length: str | None
    text: str
    qtype: str
    truth: Truth
    category: str
    stamps: list[float]
    clock: bool  # the truth's times are data.csv clock times (read in a zone)


@dataclass
class _Ctx:
    root: Path
    layout: Layout
    zone: tzinfo | None
    zone_why: str
    by_uuid: dict[str, list[dict[str, str]]]
    context: bool
    notes: list[str]
    refusal: str = ""

    @property
    def csv_path(self) -> Path:
        return self.layout.csv or self.root / "data.csv"

    def need_zone(self, what: str) -> tzinfo:
        if self.zone is None:
            raise InputError(
                self.refusal
                or f"{what} holds clock times, and nothing in this layout ({self.layout.what}) tells "
                "their time zone: give --tz (UTC-5 for the RAVEN release, UTC-8 for ReMEmbR's)"
            )
        return self.zone


def load(path: str, tz: str | None = None, context: bool = True, **_: Any) -> list[Episode]:
    """NaVQA episodes: one per question clip (human_qa.json or qa_unfilled.json), else one per
    sequence (see the module docstring for layouts, time zones and checks)."""
    root = Path(path)
    if not root.is_dir():
        raise InputError(f"NaVQA folder {root} does not exist")
    layout = find_layout(root)
    csv_rows = read_data_csv(layout.csv) if layout.csv else []
    by_uuid: dict[str, list[dict[str, str]]] = {}
    for r in csv_rows:
        by_uuid.setdefault(r["uuid"], []).append(r)
    seqs = sorted({r["seq"] for r in csv_rows} | layout.sequences(), key=natural_key)
    if not seqs:
        raise InputError(
            f"{root}: no data.csv and no questions/<seq>/human_qa.json (NaVQA layouts: the RAVEN or "
            "ReMEmbR repository, its data folder, or data.csv + questions/<seq>/human_qa.json)"
        )
    frames: dict[str, SeqFrames] = {}
    for seq in seqs:
        folder = frames_folder(layout.frame_roots, seq)
        if folder is not None:
            frames[seq] = load_frames(folder)
    zone, why, refusal = _zone(tz, layout, seqs, csv_rows, frames)
    ctx = _Ctx(root, layout, zone, why, by_uuid, context, [], refusal)
    _cross_check(ctx, seqs)
    missing = [s for s in seqs if s not in frames]
    episodes: list[Episode] = []
    for seq in seqs:
        if seq in frames:
            episodes += _sequence(ctx, seq, frames[seq], [r for r in csv_rows if r["seq"] == seq])
    if missing:
        dropped = sum(_question_count(ctx, s, csv_rows) for s in missing)
        where = " or ".join(f"{r}/coda_data/<seq>/" for r in layout.frame_roots)
        ctx.notes.append(
            f"sequence(s) {', '.join(missing)} have no frames ({where} or frames/<seq>/poses.csv): "
            f"their {dropped} question(s) are left out"
        )
    if not episodes:
        raise InputError(f"{root}: no sequence has frames ({ctx.notes[-1] if ctx.notes else 'none found'})")
    label = zone_label(zone) if zone is not None else "not needed (no data.csv clock time is read)"
    for ep in episodes:
        ep.meta["zone"] = f"NaVQA data.csv clock times: {label} ({why})"
        ep.meta["time_rule"] = (
            f"NaVQA ({layout.what}): data.csv clock times read in {label} ({why}); a truth outside its "
            f"recording (more than {MARGIN_S:g} s) is a truth error, never moved to a frame"
        )
        ep.meta["notes"] = list(ctx.notes)
    return episodes


def _windows(layout: Layout, seq: str) -> dict[str, tuple[float, float]]:
    """Each question id's clip (Unix s) in a sequence's qa_unfilled.json and human_qa.json; items
    too broken to have one are left to the loader, which names them."""
    out: dict[str, tuple[float, float]] = {}
    for path, what in ((layout.clips(seq), "qa_unfilled.json"), (layout.human_qa(seq), "human_qa.json")):
        for item in _read_items(path, what) if path is not None else []:
            try:
                out.setdefault(str(item["id"]), (float(item["start_time"]), float(item["end_time"])))
            except (KeyError, TypeError, ValueError):
                continue
    return out


def zone_samples(
    layout: Layout, seqs: list[str], rows: list[dict[str, str]], frames: dict[str, SeqFrames]
) -> list[Sample]:
    """Every timed data.csv row with the window its truth must fall in: its clip, else (data.csv
    alone) its sequence's recording."""
    out = []
    windows = {seq: _windows(layout, seq) for seq in seqs}
    for r in rows:
        if r["type"].lower() not in TIMED or not r.get("stamp"):
            continue
        win = windows.get(r["seq"], {}).get(r["uuid"])
        if win is None and r["seq"] in frames and not windows.get(r["seq"]):
            win = frames[r["seq"]].span
        if win is not None:
            where = f"{layout.csv} line {r['line']}"
            out.append(Sample(tuple(clock_times(r["stamp"], where)), *win))
    return out


def _zone(
    tz: str | None,
    layout: Layout,
    seqs: list[str],
    rows: list[dict[str, str]],
    frames: dict[str, SeqFrames],
) -> tuple[tzinfo | None, str, str]:
    """The zone data.csv is read in, why, and the refusal to give if none can be told (see the
    module docstring): --tz, else the data (navqa_zone), else the release or human_qa.json texts."""
    if tz:
        return parse_zone(tz), "--tz", ""
    samples = zone_samples(layout, seqs, rows, frames)
    if samples:
        inf: Inferred = infer_zone(samples, str(layout.csv))
        return inf.zone, inf.why, inf.refusal
    if layout.release:
        rel = RELEASES[layout.release]
        return rel.zone, f"{rel.about}; layout: {layout.what}", ""
    for seq in seqs:
        hq = layout.human_qa(seq)
        if hq is not None:
            off = text_offset(_read_items(hq, "human_qa.json"))
            if off is not None:
                return offset_zone(off), f"the offset {hq.name}'s question texts are written in", ""
    return None, "", ""


def _cross_check(ctx: _Ctx, seqs: list[str]) -> None:
    """Note when human_qa.json's texts are written in another offset than data.csv is read in."""
    if ctx.zone is None:
        return
    for seq in seqs:
        hq = ctx.layout.human_qa(seq)
        off = text_offset(_read_items(hq, "human_qa.json")) if hq is not None else None
        if off is None:
            continue
        start = _read_items(hq, "human_qa.json")[0].get("start_time", 0.0) if hq else 0.0
        have = ctx.zone.utcoffset(datetime.fromtimestamp(float(start), timezone.utc))
        if have is not None and round(have.total_seconds() / 3600) != off:
            ctx.notes.append(
                f"{hq}: its question texts are written in UTC{off:+d}, data.csv is read in {zone_label(ctx.zone)}"
            )
        return


def _question_count(ctx: _Ctx, seq: str, csv_rows: list[dict[str, str]]) -> int:
    hq = ctx.layout.human_qa(seq)
    if hq is not None:
        return len(_read_items(hq, "human_qa.json"))
    return sum(1 for r in csv_rows if r["seq"] == seq)


def _sequence(ctx: _Ctx, seq: str, frames: SeqFrames, rows: list[dict[str, str]]) -> list[Episode]:
    hq = ctx.layout.human_qa(seq)
    if hq is not None:
        return _clip_episodes(ctx, seq, frames, _clips_from_human_qa(ctx, hq))
    unfilled = ctx.layout.clips(seq)
    if unfilled is not None:
        return _clip_episodes(ctx, seq, frames, _clips_from_unfilled(ctx, unfilled, frames))
    return [_sequence_episode(ctx, seq, frames, rows)]


def _check_type(qtype: str, where: str) -> None:
    if qtype not in TYPES:
        raise InputError(f"{where}: type {qtype!r} is not one of {', '.join(TYPES)}")


def _clips_from_human_qa(ctx: _Ctx, hq: Path) -> list[_Clip]:
    out = []
    for n, item in enumerate(_read_items(hq, "human_qa.json")):
        where = f"{hq} item {n}"
        try:
            qid, t0, t1 = str(item["id"]), float(item["start_time"]), float(item["end_time"])
            qtype = str(item["type"]).lower()
        except (KeyError, TypeError, ValueError) as e:
            raise InputError(f"{where}: missing or bad field {e}") from e
        _check_type(qtype, where)
        truth = _truth_from_json(item)
        row = (ctx.by_uuid.get(qid) or [{}])[0]
        text = row.get("question") or str(item.get("question", "")).split("\n")[-1].strip()
        out.append(
            _Clip(
                qid,
                t0,
                t1,
                item.get("length_category"),
                text,
                qtype,
                truth,
                row.get("category", ""),
                list(truth.times),
                False,
            )
        )
    return out


def _clip_from_row(
    ctx: _Ctx, row: dict[str, str], frames: SeqFrames, window: tuple[float, float], length: str | None
) -> _Clip:
    """A data.csv question over a window of the sequence, its truth read in the episode's zone."""
    where = f"{ctx.csv_path} line {row['line']}"
    qtype = row["type"].lower()
    _check_type(qtype, where)
    timed = row.get("stamp") and qtype in TIMED
    zone = ctx.need_zone(str(ctx.csv_path)) if timed else (ctx.zone or timezone.utc)
    got = _truth_from_csv(row, frames, window, zone, where)
    return _Clip(
        row["uuid"],
        *window,
        length,
        row["question"],
        qtype,
        got.truth,
        row.get("category", ""),
        got.stamps,
        True,
    )


def _clips_from_unfilled(ctx: _Ctx, path: Path, frames: SeqFrames) -> list[_Clip]:
    out = []
    for n, item in enumerate(_read_items(path, "qa_unfilled.json")):
        try:
            qid, t0, t1 = str(item["id"]), float(item["start_time"]), float(item["end_time"])
        except (KeyError, TypeError, ValueError) as e:
            raise InputError(f"{path} item {n}: missing or bad field {e}") from e
        for row in ctx.by_uuid.get(qid, []):  # a clip may carry several questions
            out.append(_clip_from_row(ctx, row, frames, (t0, t1), item.get("length_category")))
    return out


def _question(ctx: _Ctx, c: _Clip, qid: str, text: str, t0: float, t1: float) -> Question:
    meta: dict[str, Any] = {}
    zone = ctx.zone or timezone.utc
    err = check_inside(c.stamps, t0, t1, zone, c.clock) if c.stamps else None
    if err:
        meta["truth_error"] = err
    elif not _scorable(c.qtype, c.truth):
        meta["unscorable"] = "no parsable ground truth"
    return Question(
        id=qid,
        text=text,
        type=cast(EvalType, c.qtype),
        truth=c.truth,
        category=c.category.lower(),
        horizon=_horizon(qid, c.length),
        meta=meta,
    )


def _clip_episodes(ctx: _Ctx, seq: str, frames: SeqFrames, clips: list[_Clip]) -> list[Episode]:
    by_window: dict[tuple[float, float], list[Question]] = {}
    for c in clips:
        refs = frames.window(c.t0, c.t1)
        if not refs:
            raise InputError(f"question {c.qid}: no frames of sequence {seq} between {c.t0} and {c.t1}")
        text = _context(c.text, refs[-1].pose) if ctx.context and refs[-1].pose is not None else c.text
        by_window.setdefault((c.t0, c.t1), []).append(_question(ctx, c, c.qid, text, refs[0].t, refs[-1].t))
    out = []
    for (t0, t1), qs in sorted(by_window.items()):
        name = f"navqa/{seq}@{t0:.3f}-{t1:.3f}"
        out.append(_episode(ctx.root, name, f"{seq}:{t0:.3f}:{t1:.3f}", frames.window(t0, t1), qs))
    return out


def _sequence_episode(ctx: _Ctx, seq: str, frames: SeqFrames, rows: list[dict[str, str]]) -> Episode:
    qs = []
    last = frames.refs[-1].pose
    for row in rows:
        c = _clip_from_row(ctx, row, frames, frames.span, None)
        text = _context(c.text, last) if ctx.context and last is not None else c.text
        qs.append(_question(ctx, c, c.qid, text, *frames.span))
    return _episode(ctx.root, f"navqa/{seq}", f"{seq}:all", frames.refs, qs)


def _episode(root: Path, name: str, key: str, refs: list[FrameRef], qs: list[Question]) -> Episode:
    times = [r.t for r in refs]
    for q in qs:
        q.horizon = q.horizon or horizon_of(times[-1] - times[0] if len(times) > 1 else None)
    traj = [(r.t, r.pose.x, r.pose.y) for r in refs if r.pose is not None]
    return Episode(
        id=name,
        dataset="navqa",
        key=f"navqa:{root.resolve()}:{key}",
        frames=lambda: RefSource(name, refs),
        questions=qs,
        frame_times=times,
        trajectory=traj,
        pos_threshold=POS_THRESHOLD,
    )


DATASETS.register("navqa")(load)
