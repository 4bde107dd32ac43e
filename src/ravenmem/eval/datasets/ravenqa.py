"""RAVEN-QA: a folder per video with `frames/*.jpg` and a `questions.json`; also our export format.

Layout (`raven-qa:PATH`; PATH is the dataset folder, a subset folder, a split folder or one video):

    the release (huggingface.co/datasets/zzcnewly/RAVEN_QA, placed under data/ as its README says):
    PATH/{habitat_sim,real_world,irs,irs_hard}/[<group>/]<video>/frames/*.jpg + questions.json
    ours and older exports:
    PATH/<subset>/[simple|hard/]<video>/frames/frame_0001.jpg ...   frames, ordered by natural sort
    PATH/<subset>/[simple|hard/]<video>/questions.json

Every folder under PATH holding a questions.json is a video. When a folder above it carries one
of the release's subset names, that is its subset and the release's split goes with it: `irs`
(the human-ego videos) is the simple split, `irs_hard` the hard one, `habitat_sim` and
`real_world` (robot-ego) have none (a simple / hard folder right above the video still names one). Otherwise its subset is the nearest folder above it that is
not named simple/hard and its split such a folder right above it (or the one above that), else a
top-level `"split"` in questions.json, else an optional fifth element of a question row.

`questions.json` keys (all but the question list optional):

    "questions (ques, answer_in_filename, category, query_img)": [[question, answer, category, query_img], ...]
    "questions (ques, answer_in_position)": [[question, answer], ...]      (older videos; "questions" also read)
    "timestamp_to_filename": {"HH:MM:SS": "frame_0042.jpg", ...}
    "timestamp_to_position": {"HH:MM:SS": [x, y, z] or "frame_0042.jpg", ...}
    "filename_to_position": {"frame_0042.jpg": [x, y, z], ...}

The release's own converter reads `timestamp_to_position` before `timestamp_to_filename` and
takes an entry holding a file name as that frame's time; both are read here the same way.

An answer is a filename, an [x, y, z], a `[[x, y, z], filename]` pair, or a list of those (any
one of them is right). Categories: dominant, secondary, reasoning, information recall, spatial.

Scoring: a question whose answer names frames of the video is a `frame` question, right when
the answer names one of them (the paper's target retrieval accuracy; the nearest frame to the
answer's time, so exactly that frame by default); its position accuracy is reported beside it
when the frames have positions. A question answered by a position only is a `position` question.

The times the release gives the answer frames (from those two maps; a position answer gets the
time of the `timestamp_to_position` entry within 1 cm of it in x, y) are kept as the truth's
`times`: the release scorer's rule (`--scoring release`) compares an answer's time with them.

Frame times: frames named in `timestamp_to_filename` (or by file name in `timestamp_to_position`) get that time of day; the others are
interpolated by frame order between them (and continue at the neighbouring rate outside);
without any, frame i is at i / `rate` seconds (default 1 fps). Times of day are placed on
2000-01-01 UTC. Poses: `filename_to_position`, else `timestamp_to_position` interpolated in
time, else interpolated by frame order between known frames; a video with no position at all
is ingested at the origin and its questions are scored by frame only.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ...errors import InputError
from ...fsio import read_text
from ...types import Frame, Pose
from ..types import Episode, EvalType, Question, Truth, horizon_of
from . import DATASETS
from .frames import (
    BASE_DAY,
    FrameRef,
    RefSource,
    interpolate_positions,
    interpolate_times,
    list_images,
    natural_key,
    parse_hms,
)

QUESTION_KEYS = (
    "questions (ques, answer_in_filename, category, query_img)",
    "questions (ques, answer_in_position)",
    "questions (ques, answer_in_filename)",
    "questions",
)
CATEGORIES = ("dominant", "secondary", "reasoning", "information recall", "spatial")
SPLITS = ("simple", "hard", "easy")
# The release's subsets and the split each one is (human-ego irs / irs_hard; robot-ego none)
RELEASE_SUBSETS = {"habitat_sim": "", "real_world": "", "irs": "simple", "irs_hard": "hard"}
# Position threshold (m) when the user gives none: our default, not the paper's (RAVEN-QA files do
# not carry one; the release scorer's --pos_threshold defaults to 0.1 m). Override with
# --pos-threshold M, or per subset --pos-threshold real_world=3,habitat_sim=1.
DEFAULT_POS_THRESHOLD = 2.0
POSITION_MATCH_M = 0.01  # the release converter matches an answer position to a timestamp within 1 cm


def _subset_split(vdir: Path) -> tuple[str, str]:
    """(subset, split) of a video folder: a release subset folder above it and its split, else
    the nearest folder above it that is not a split name, and a `simple` / `hard` folder among
    the two folders right above it ("" when none)."""
    above = list(vdir.resolve().parent.parts)[::-1]
    split = next((p.lower() for p in above[:2] if p.lower() in SPLITS), "")
    release = next((p for p in above if p.lower() in RELEASE_SUBSETS), None)
    if release is not None:
        return release.lower(), split or RELEASE_SUBSETS[release.lower()]
    subset = next((p for p in above if p.lower() not in SPLITS), "")
    return subset, split


def _group(vdir: Path, subset: str) -> list[str]:
    """Folders between the subset folder and the video (e.g. the release's indoor / outdoor)."""
    parts = list(vdir.resolve().parent.parts)
    if subset not in parts:
        return []
    below = parts[len(parts) - parts[::-1].index(subset) :]
    return [p for p in below if p.lower() not in SPLITS]


def find_videos(root: Path) -> list[tuple[str, str, Path]]:
    """(subset, split, video folder) for every folder at or under root holding a questions.json."""
    if not root.is_dir():
        raise InputError(f"RAVEN-QA folder {root} does not exist")
    if (root / "questions.json").exists():
        vdirs = [root]
    else:
        vdirs = sorted({q.parent for q in root.rglob("questions.json")})
    if not vdirs:
        raise InputError(
            f"{root}: no <video>/questions.json found (RAVEN-QA layout: <subset>/[simple|hard/]<video>/frames, "
            "questions.json)"
        )
    found = [(*_subset_split(v), v) for v in vdirs]
    return sorted(found, key=lambda f: (natural_key(f[0]), f[1], natural_key(str(f[2]))))


def _is_xyz(v: Any) -> bool:
    return isinstance(v, list) and 2 <= len(v) <= 3 and all(isinstance(x, (int, float)) for x in v)


def parse_answer(ans: Any, where: str) -> list[tuple[list[float] | None, str | None]]:
    """All accepted (position, file) pairs of one RAVEN-QA answer."""
    if isinstance(ans, str) and ans.strip():
        return [(None, ans.strip())]
    if _is_xyz(ans):
        return [([float(x) for x in ans], None)]
    if isinstance(ans, list) and len(ans) == 2 and _is_xyz(ans[0]) and isinstance(ans[1], str):
        return [([float(x) for x in ans[0]], ans[1])]
    if isinstance(ans, list) and ans:
        return [item for a in ans for item in parse_answer(a, where)]
    raise InputError(
        f"{where}: answer {ans!r} is not a filename, an [x, y, z], [[x, y, z], file] or a list of those"
    )


def load_video(
    subset: str, vdir: Path, rate: float = 1.0, pos_threshold: float | None = None, split: str = ""
) -> Episode:
    """One RAVEN-QA video folder as an Episode."""
    qpath = vdir / "questions.json"
    try:
        data = json.loads(read_text(qpath, what="question file"))
    except (OSError, ValueError) as e:  # ValueError: not UTF-8, not JSON
        raise InputError(f"{qpath}: cannot read JSON ({e})") from e
    if not isinstance(data, dict):
        raise InputError(f"{qpath}: top level must be an object")
    fdir = vdir / "frames"
    if not fdir.is_dir():
        raise InputError(f"{vdir}: no frames/ folder")
    files = list_images(fdir)
    if not files:
        raise InputError(f"{fdir}: no image files")
    names = [p.name for p in files]
    index = {n: i for i, n in enumerate(names)}

    def idx_of(name: str) -> int | None:
        return index.get(Path(str(name)).name)

    anchors: dict[int, float] = {}
    for key in ("timestamp_to_filename", "timestamp_to_position"):
        for hms, val in _mapping(data, key, qpath).items():
            i = idx_of(val) if isinstance(val, str) else None
            if i is not None:
                anchors[i] = parse_hms(hms, f"{qpath} {key}")
    try:
        secs = interpolate_times(len(files), anchors, rate)
    except InputError as e:
        raise InputError(f"{qpath}: {e}") from None
    times = [BASE_DAY + s for s in secs]

    known: dict[int, list[float]] = {}
    for fname, pos in (data.get("filename_to_position") or {}).items():
        i = idx_of(fname)
        if i is not None and _is_xyz(pos):
            known[i] = [float(v) for v in pos]
    t2p = _mapping(data, "timestamp_to_position", qpath)
    if t2p:
        pts = sorted(
            (parse_hms(h, f"{qpath} timestamp_to_position"), p) for h, p in t2p.items() if _is_xyz(p)
        )
        if pts:
            ts = np.asarray([BASE_DAY + s for s, _ in pts])
            arr = np.asarray([list(p) + [0.0] * (3 - len(p)) for _, p in pts], dtype=float)
            for i, t in enumerate(times):
                if i not in known:
                    known[i] = [float(np.interp(t, ts, arr[:, k])) for k in range(3)]
    positions = interpolate_positions(len(files), known)
    has_poses = bool(known)

    refs = [
        FrameRef(t=t, pose=Pose(p[0], p[1], p[2]) if p else Pose(0.0, 0.0), path=f, index=i)
        for i, (f, t, p) in enumerate(zip(files, times, positions))
    ]
    split = str(data.get("split") or split).lower()
    name = "/".join(x for x in (subset, split, *_group(vdir, subset), vdir.name) if x)
    duration = times[-1] - times[0] if len(times) > 1 else None
    where = _Where(qpath, vdir, name, subset, split, horizon_of(duration))
    questions = _questions(data, where, positions, index, has_poses, release_stamps(data, qpath))
    period = float(np.median(np.diff(times))) if len(times) > 1 else 1.0 / rate
    rule = (
        "frame times from timestamp_to_filename, interpolated by frame order in between"
        if anchors
        else f"frame i at i / {rate:g} s (no timestamp_to_filename; --rate)"
    )
    return Episode(
        id=name,
        dataset="raven-qa",
        key=f"raven-qa:{vdir.resolve()}:rate={rate}",
        frames=lambda: RefSource(name, refs),
        questions=questions,
        frame_times=times,
        frame_files=names,
        trajectory=[(t, p[0], p[1]) for t, p in zip(times, positions) if p is not None],
        has_poses=has_poses,
        pos_threshold=pos_threshold or DEFAULT_POS_THRESHOLD,
        frame_tol=0.5 * period,  # the named frame itself: the nearest frame to the answer's time
        meta={"subset": subset, "split": split, "frames": len(files), "time_rule": rule},
    )


@dataclass
class _Where:
    """Where a video's questions come from and what every one of them shares."""

    qpath: Path
    vdir: Path
    name: str
    subset: str
    split: str
    horizon: str


def _questions(
    data: dict[str, Any],
    w: _Where,
    positions: list[list[float] | None],
    index: dict[str, int],
    has_poses: bool,
    stamps: Stamps,
) -> list[Question]:
    key = next((k for k in QUESTION_KEYS if k in data), None)
    if key is None:
        raise InputError(f"{w.qpath}: no question list (expected key {QUESTION_KEYS[0]!r})")
    rows = data[key]
    if not isinstance(rows, list):
        raise InputError(f"{w.qpath}: {key!r} must be a list")
    f2p = {Path(k).name: v for k, v in (data.get("filename_to_position") or {}).items() if _is_xyz(v)}
    out: list[Question] = []
    for n, row in enumerate(rows):
        where = f"{w.qpath} question {n}"
        if not isinstance(row, list) or len(row) < 2 or not isinstance(row[0], str):
            raise InputError(
                f"{where}: expected [question, answer, (category, query_img, split)], got {row!r}"
            )
        truth = Truth()
        given: list[list[float]] = []  # positions written in the answer itself
        for pos, fname in parse_answer(row[1], where):
            if pos is not None:
                given.append(pos)
            if fname is not None:
                base = Path(fname).name
                truth.files.append(base)
                if pos is None and base in f2p:
                    pos = [float(v) for v in f2p[base]]
                if pos is None and has_poses and base in index:
                    pos = positions[index[base]]
            if pos is not None:
                truth.positions.append(list(pos) + [0.0] * (3 - len(pos)))
        truth.times = _release_times(truth.files, given, stamps)
        category = str(row[2]).strip().lower() if len(row) > 2 and row[2] else ""
        image = _query_image(row[3], w.vdir, where) if len(row) > 3 and row[3] else None
        split = str(row[4]).strip().lower() if len(row) > 4 and row[4] else w.split
        # the paper's target retrieval: the answer names the right frame; a position only when no frame is named
        qtype: EvalType = "frame" if any(f in index for f in truth.files) else "position"
        if qtype == "position" and not truth.positions:
            raise InputError(f"{where}: answer names no frame of this video and no position")
        q = Question(id=f"{w.name}#{n}", text=row[0].strip(), type=qtype, truth=truth, category=category)
        q.horizon, q.image, q.subset, q.split = w.horizon, image, w.subset, split
        out.append(q)
    return out


def _query_image(ref: Any, vdir: Path, where: str) -> Path:
    rel = str(ref)
    for cand in (vdir / rel, vdir / "frames" / rel, vdir / "query_images" / rel, vdir / "query_imgs" / rel):
        if cand.is_file():
            return cand
    hits = sorted(vdir.rglob(Path(rel).name))
    if hits:
        return hits[0]
    raise InputError(f"{where}: query image {rel!r} not found under {vdir}")


def _mapping(data: dict[str, Any], key: str, qpath: Path) -> dict[str, Any]:
    val = data.get(key) or {}
    if not isinstance(val, dict):
        raise InputError(f'{qpath}: {key!r} must be an object of "HH:MM:SS": value')
    return val


@dataclass
class Stamps:
    """The times the release's converter gives answers: per frame file, and per x, y position."""

    files: dict[str, float]
    positions: list[tuple[float, float, float]]  # (x, y, seconds)


def release_stamps(data: dict[str, Any], qpath: Path) -> Stamps:
    """As the release's converter reads them: `timestamp_to_position` when present, else
    `timestamp_to_filename`; an entry is a frame file name or an [x, y(, z)] position."""
    key = "timestamp_to_position" if "timestamp_to_position" in data else "timestamp_to_filename"
    files: dict[str, float] = {}
    positions: list[tuple[float, float, float]] = []
    for hms, val in _mapping(data, key, qpath).items():
        secs = parse_hms(hms, f"{qpath} {key}")
        if isinstance(val, str):
            files[Path(val).name] = secs
        elif _is_xyz(val):
            positions.append((float(val[0]), float(val[1]), secs))
    return Stamps(files, positions)


def _release_times(files: list[str], positions: list[list[float]], stamps: Stamps) -> list[float]:
    """The truth's instants by the release's rule: an answer frame's stamp, else (for a
    position answer) the stamp of a position within 1 cm in x, y; on the base day."""
    out = [stamps.files[f] for f in files if f in stamps.files]
    if not out:
        for p in positions:
            hit = next(
                (
                    s
                    for x, y, s in stamps.positions
                    if abs(x - p[0]) < POSITION_MATCH_M and abs(y - p[1]) < POSITION_MATCH_M
                ),
                None,
            )
            if hit is not None:
                out.append(hit)
    return sorted({BASE_DAY + s for s in out})


def load(path: str, rate: float = 1.0, **_: Any) -> list[Episode]:
    """All videos under a RAVEN-QA folder (see the module docstring for the layout)."""
    if rate <= 0:
        raise InputError(f"rate must be > 0 frames per second, got {rate}")
    return [
        load_video(subset, vdir, rate=rate, split=split) for subset, split, vdir in find_videos(Path(path))
    ]


def export_episode(out_dir: str | Path, frames: list[Frame], questions: list[dict[str, Any]]) -> Path:
    """Write frames and questions in RAVEN-QA layout (how our simulated episodes are shared).

    `questions`: dicts with `question`, `answer` (a RAVEN-QA answer: filename, [x, y, z],
    [[x, y, z], filename] or a list), optional `category` and `query_img`. Every frame gets its
    position in `filename_to_position`, and the first frame of every whole second its time in
    `timestamp_to_filename` (HH:MM:SS of the frame's UTC time of day).
    """
    out = Path(out_dir)
    (out / "frames").mkdir(parents=True, exist_ok=True)
    from ...imageio import write_jpeg

    f2p: dict[str, list[float]] = {}
    t2f: dict[str, str] = {}
    for i, f in enumerate(frames):
        name = f"frame_{i:06d}.jpg"
        write_jpeg(out / "frames" / name, f.image, quality=92)
        if f.pose is not None:
            f2p[name] = [round(f.pose.x, 4), round(f.pose.y, 4), round(f.pose.z, 4)]
        sod = int(f.t - BASE_DAY) % 86400 if f.t >= BASE_DAY else int(f.t) % 86400
        hms = f"{sod // 3600:02d}:{sod % 3600 // 60:02d}:{sod % 60:02d}"
        t2f.setdefault(hms, name)
    rows = [[q["question"], q["answer"], q.get("category", ""), q.get("query_img")] for q in questions]
    doc = {QUESTION_KEYS[0]: rows, "timestamp_to_filename": t2f, "filename_to_position": f2p}
    (out / "questions.json").write_text(json.dumps(doc, indent=1), encoding="utf-8")
    return out


DATASETS.register("raven-qa")(load)
DATASETS.register("ravenqa")(load)
