"""NaVQA (ReMEmbR's benchmark over CODa): `data.csv`, per-sequence `human_qa.json`, and frames.

Layout (`navqa:PATH`):

    PATH/data.csv                          UUID, Seq ID, Question, Timestamp with answer, Type
                                           (binary/position/time/text/duration), Text answer,
                                           Parsable answer, Question Category
    PATH/questions/<seq>/human_qa.json     (or PATH/<seq>/human_qa.json) {"data": [{id, length_category,
                                           start_time, end_time, question, type, answers: {position |
                                           time (minutes ago) | duration (minutes) | text: [...]}}]}
    frames, from your CODa conversion, either
    PATH/coda_data/<seq>/<unix time>.pkl   ReMEmbR's conversion: dict with cam0 (BGR image), position
                                           [x, y, z], rotation [qx, qy, qz, qw], timestamp
    PATH/frames/<seq>/poses.csv            ours: header with file,t,x,y,z[,qx,qy,qz,qw] (files relative
                                           to that folder), the CSV the folder source reads

With `human_qa.json`, every question gets a memory of its own clip (start_time..end_time of
the sequence) and its answers from there; `data.csv` adds categories. With `data.csv` alone,
the memory is the whole sequence and answers come from the "Timestamp with answer" column
(local time in `tz`, America/Chicago for CODa): positions are the pose at that time, times
that instant, durations the parsable minutes. Pickles are read with an unpickler that only
builds numpy arrays, so a tampered file cannot run code.
"""

from __future__ import annotations

import csv
import io
import json
import pickle
from collections.abc import Callable
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path
from typing import Any, cast
from zoneinfo import ZoneInfo

import numpy as np

from ...errors import InputError
from ...fsio import read_text
from ...ingest.poses import read_pose_table
from ...types import Pose
from ..types import Episode, EvalType, Question, Truth, horizon_of
from . import DATASETS
from .frames import FrameRef, RefSource, natural_key

POS_THRESHOLD = 15.0  # metres, NaVQA's position criterion
TYPES = ("binary", "position", "time", "text", "duration")
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

    def window(self, t0: float, t1: float) -> list[FrameRef]:
        return [r for r in self.refs if t0 <= r.t <= t1]

    def pose_at(self, t: float) -> Pose:
        ts = self.times
        i = int(np.clip(np.searchsorted(ts, t), 0, len(ts) - 1))
        if i > 0 and abs(ts[i - 1] - t) < abs(ts[i] - t):
            i -= 1
        pose = self.refs[i].pose
        assert pose is not None
        return pose


def load_frames(root: Path, seq: str) -> SeqFrames:
    csv_path = root / "frames" / seq / "poses.csv"
    if csv_path.exists():
        table = read_pose_table(csv_path)
        if table.files is None or table.t is None:
            raise InputError(f"{csv_path}: needs a header with file and t columns")
        refs = []
        for i in range(len(table)):
            q = table.quat[i] if table.quat is not None else None
            x, y, z = (float(v) for v in table.xyz[i])
            pose = Pose.from_quaternion(x, y, z, *map(float, q)) if q is not None else Pose(x, y, z)
            refs.append(FrameRef(t=float(table.t[i]), pose=pose, path=csv_path.parent / table.files[i]))
        refs.sort(key=lambda r: r.t)
    else:
        pdir = root / "coda_data" / seq
        pkls = sorted(pdir.glob("*.pkl"), key=lambda p: natural_key(p.stem)) if pdir.is_dir() else []
        if not pkls:
            raise InputError(f"sequence {seq}: no frames (expected {csv_path} or {pdir}/*.pkl)")
        refs = []
        for p in pkls:
            d = read_coda_pickle(p)
            pos = [float(v) for v in np.asarray(d["position"]).ravel()[:3]]
            rot = np.asarray(d.get("rotation", []), dtype=float).ravel()
            x, y, z = (pos + [0.0, 0.0, 0.0])[:3]
            pose = Pose.from_quaternion(x, y, z, *map(float, rot[:4])) if rot.size == 4 else Pose(x, y, z)
            t = float(d.get("timestamp", p.stem))
            refs.append(FrameRef(t=t, pose=pose, load=_loader(p)))
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


def _hms_times(stamp: str, day_of: float, tz: ZoneInfo, where: str) -> list[float]:
    """'7:59:00' or '07:56:38,07:59:00' (local time on the sequence's day) -> Unix seconds."""
    day = datetime.fromtimestamp(day_of, tz).date()
    out = []
    for part in stamp.split(","):
        try:
            hms = datetime.strptime(part.strip(), "%H:%M:%S").time()
        except ValueError:
            raise InputError(f"{where}: timestamp {part.strip()!r} is not H:MM:SS") from None
        out.append(datetime.combine(day, hms, tzinfo=tz).timestamp())
    return out


def _horizon(qid: str, length_category: str | None) -> str:
    for h in ("short", "medium", "long"):
        if (length_category or "").lower() == h or f"{h.upper()}_" in qid:
            return h
    return ""


def _yes(text: str) -> bool | None:
    w = text.strip().lower().rstrip(".!")
    return True if w.startswith("yes") else False if w.startswith("no") else None


def _truth_from_csv(row: dict[str, str], frames: SeqFrames, tz: ZoneInfo, where: str) -> Truth:
    qtype = row["type"].lower()
    truth = Truth()
    stamps = _hms_times(row["stamp"], float(frames.refs[0].t), tz, where) if row.get("stamp") else []
    if qtype == "position" and stamps:
        truth.positions = [list(frames.pose_at(t).xyz) for t in stamps]
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
    return truth


def _truth_from_json(item: dict[str, Any], where: str) -> Truth:
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


def _find_human_qa(root: Path, seq: str) -> Path | None:
    for cand in (
        root / "questions" / seq / "human_qa.json",
        root / seq / "human_qa.json",
        root / "human_qa" / f"{seq}.json",
    ):
        if cand.exists():
            return cand
    return None


def _context(q: str, pose: Pose) -> str:
    return f"You are now at position [{pose.x:.2f}, {pose.y:.2f}, {pose.z:.2f}] (metres, map frame). {q}"


def load(path: str, tz: str = "America/Chicago", context: bool = True, **_: Any) -> list[Episode]:
    """NaVQA episodes: one per question clip with human_qa.json, else one per sequence."""
    root = Path(path)
    if not root.is_dir():
        raise InputError(f"NaVQA folder {root} does not exist")
    try:
        zone = ZoneInfo(tz)
    except (KeyError, ValueError) as e:
        raise InputError(f"unknown time zone {tz!r} ({e})") from e
    csv_rows = read_data_csv(root / "data.csv") if (root / "data.csv").exists() else []
    by_uuid = {r["uuid"]: r for r in csv_rows}
    seqs = sorted(
        {r["seq"] for r in csv_rows}
        | {p.parent.name for p in root.glob("questions/*/human_qa.json")}
        | {p.parent.name for p in root.glob("*/human_qa.json")},
        key=natural_key,
    )
    if not seqs:
        raise InputError(f"{root}: no data.csv and no questions/<seq>/human_qa.json (NaVQA layout)")
    episodes: list[Episode] = []
    for seq in seqs:
        frames = load_frames(root, seq)
        hq = _find_human_qa(root, seq)
        if hq is not None:
            episodes += _clip_episodes(root, seq, hq, frames, by_uuid, context)
        else:
            episodes.append(
                _sequence_episode(root, seq, frames, [r for r in csv_rows if r["seq"] == seq], zone, context)
            )
    return episodes


def _clip_episodes(
    root: Path, seq: str, hq: Path, frames: SeqFrames, by_uuid: dict[str, dict[str, str]], context: bool
) -> list[Episode]:
    try:
        items = json.loads(read_text(hq, what="question file"))["data"]
    except (OSError, json.JSONDecodeError, KeyError, TypeError) as e:
        raise InputError(f"{hq}: not a human_qa.json ({e})") from e
    clips: dict[tuple[float, float], list[Question]] = {}
    for n, item in enumerate(items):
        where = f"{hq} item {n}"
        try:
            qid, t0, t1 = str(item["id"]), float(item["start_time"]), float(item["end_time"])
            qtype = str(item["type"]).lower()
        except (KeyError, TypeError, ValueError) as e:
            raise InputError(f"{where}: missing or bad field {e}") from e
        if qtype not in TYPES:
            raise InputError(f"{where}: type {qtype!r} is not one of {', '.join(TYPES)}")
        truth = _truth_from_json(item, where)
        row = by_uuid.get(qid, {})
        text = row.get("question") or str(item.get("question", "")).split("\n")[-1].strip()
        clip = frames.window(t0, t1)
        if not clip:
            raise InputError(f"{where}: no frames of sequence {seq} between {t0} and {t1}")
        if context and clip[-1].pose is not None:
            text = _context(text, clip[-1].pose)
        q = Question(
            id=qid,
            text=text,
            type=cast(EvalType, qtype),
            truth=truth,
            category=row.get("category", "").lower(),
            horizon=_horizon(qid, item.get("length_category")),
            meta={} if _scorable(qtype, truth) else {"unscorable": "no parsable ground truth"},
        )
        clips.setdefault((t0, t1), []).append(q)
    out = []
    for (t0, t1), qs in sorted(clips.items()):
        refs = frames.window(t0, t1)
        name = f"navqa/{seq}@{t0:.3f}-{t1:.3f}"
        out.append(_episode(root, name, f"{seq}:{t0:.3f}:{t1:.3f}", refs, qs))
    return out


def _sequence_episode(
    root: Path, seq: str, frames: SeqFrames, rows: list[dict[str, str]], zone: ZoneInfo, context: bool
) -> Episode:
    qs = []
    last = frames.refs[-1].pose
    for row in rows:
        where = f"{root / 'data.csv'} line {row['line']}"
        qtype = row["type"].lower()
        if qtype not in TYPES:
            raise InputError(f"{where}: type {qtype!r} is not one of {', '.join(TYPES)}")
        truth = _truth_from_csv(row, frames, zone, where)
        text = _context(row["question"], last) if context and last is not None else row["question"]
        qs.append(
            Question(
                id=row["uuid"],
                text=text,
                type=cast(EvalType, qtype),
                truth=truth,
                category=row.get("category", "").lower(),
                horizon=_horizon(row["uuid"], None),
                meta={} if _scorable(qtype, truth) else {"unscorable": "no parsable ground truth"},
            )
        )
    return _episode(root, f"navqa/{seq}", f"{seq}:all", frames.refs, qs)


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
