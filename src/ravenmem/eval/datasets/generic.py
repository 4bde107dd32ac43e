"""Our own questions over any recording: a `questions.json` next to a TUM folder, video, bag, image
folder or an existing memory.

    ravenmem eval --dataset tum:../shared/data/tum_fr1_rpy --queries my_queries.json --method offline
    ravenmem eval --dataset queries:my_queries.json ...        (the file names its own "source")

Format (every field but `questions`, `question` and `answer` optional):

    {"source": "tum:../shared/data/tum_fr1_rpy",          # relative to this file; --dataset wins
     "pos_tolerance_m": 0.5, "time_tolerance_s": 2.0,      # defaults for every question
     "questions": [
       {"id": "controller", "question": "Where is the game controller?", "type": "position",
        "category": "spatial", "answer": {"position": [x, y, z], "tolerance_m": 0.5}},
       {"type": "position", "answer": {"frames": ["rgb/1305031230.1.jpg"]}},  # positions of those frames
       {"type": "time",     "answer": {"window": [3.0, 7.5]}},   # seconds from the first frame
       {"type": "time",     "answer": {"time": 12.0, "tolerance_s": 2}},   # s from start; "time_unix" absolute
       {"type": "frame",    "answer": {"frames": ["rgb/...jpg", ...], "tolerance_s": 0.5}},
       {"type": "frame",    "answer": {"frame_ranges": [["rgb/a.jpg", "rgb/b.jpg"], ...]}},  # every frame a..b
       {"type": "binary",   "answer": {"yes": true}},
       {"type": "text",     "answer": {"text": ["blue", "navy blue"]}},
       {"type": "duration", "answer": {"duration_s": 12.0, "tolerance_s": 3}},
       {"question": "Where did you see this?", "image": "query.jpg", "type": "position", "answer": {...}}]}

Frame files are mapped to times (and poses) through the recording's own index: TUM `rgb.txt`
(+ `groundtruth.txt`), a `poses.csv` with file and t columns, or file names that are Unix times.
Position answers given as frames use the poses of those frames.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, cast

from ...errors import InputError
from ...fsio import read_text
from ...types import Pose
from ..types import EVAL_TYPES, Episode, EvalType, Question, Truth
from . import DATASETS, SOURCE_FORMATS


class FrameIndex:
    """file name -> (time, pose) for the frames of a recording folder, when it can be known."""

    def __init__(self, root: Path) -> None:
        self.root = root
        self.times: dict[str, float] = {}
        self.poses: dict[str, Pose] = {}
        rgb = root / "rgb.txt" if root.is_dir() else None
        if rgb is not None and rgb.exists():
            for line in read_text(rgb, what="TUM list").splitlines():
                parts = line.split("#", 1)[0].split()
                if len(parts) >= 2:
                    self.times[parts[1]] = float(parts[0])
            gt = root / "groundtruth.txt"
            if gt.exists():
                from ...ingest.poses import load_pose_track

                track = load_pose_track(gt, sort=True)
                for f, t in self.times.items():
                    pose = track.interpolate(t)
                    if pose is not None:
                        self.poses[f] = pose
        elif root.is_dir() and (root / "poses.csv").exists():
            from ...ingest.poses import read_pose_table

            tab = read_pose_table(root / "poses.csv")
            if tab.files is not None and tab.t is not None:
                for i, f in enumerate(tab.files):
                    self.times[f] = float(tab.t[i])
                    x, y, z = (float(v) for v in tab.xyz[i])
                    self.poses[f] = Pose(x, y, z)

    def time(self, f: str, where: str) -> float:
        for key in (f, f.lstrip("./"), Path(f).name, f"rgb/{Path(f).name}"):
            if key in self.times:
                return self.times[key]
        try:
            return float(Path(f).stem)
        except ValueError:
            raise InputError(
                f"{where}: frame {f!r} is not in {self.root}'s frame index "
                f"(rgb.txt / poses.csv) and its name is not a Unix time"
            ) from None

    def pose(self, f: str, where: str) -> Pose:
        for key in (f, f.lstrip("./"), Path(f).name, f"rgb/{Path(f).name}"):
            if key in self.poses:
                return self.poses[key]
        raise InputError(f"{where}: no pose known for frame {f!r} (needs groundtruth.txt or poses.csv)")

    def ordered(self) -> list[tuple[float, str]]:
        return sorted((t, f) for f, t in self.times.items())

    def between(self, a: str, b: str, where: str) -> list[str]:
        """Every indexed frame from file a to file b (inclusive, by time)."""
        ta, tb = self.time(a, where), self.time(b, where)
        if tb < ta:
            raise InputError(f"{where}: frame range {a!r}..{b!r} runs backwards in time")
        return [f for t, f in self.ordered() if ta <= t <= tb]

    def first_time(self) -> float | None:
        return min(self.times.values()) if self.times else None


def _num_list(v: Any, n: tuple[int, ...], where: str, what: str) -> list[float]:
    if not (isinstance(v, list) and len(v) in n and all(isinstance(x, (int, float)) for x in v)):
        raise InputError(f"{where}: {what} must be a list of {' or '.join(map(str, n))} numbers, got {v!r}")
    return [float(x) for x in v]


def parse_question(
    q: Any, n: int, base: Path, index: FrameIndex, defaults: dict[str, Any], where0: str
) -> Question:
    where = f"{where0} question {n}"
    if not isinstance(q, dict):
        raise InputError(f"{where}: must be an object")
    text = q.get("question")
    if not isinstance(text, str) or not text.strip():
        raise InputError(f"{where}: missing 'question'")
    qtype = q.get("type", "")
    if qtype not in EVAL_TYPES:
        raise InputError(f"{where}: type {qtype!r} is not one of {', '.join(EVAL_TYPES)}")
    a = q.get("answer")
    if not isinstance(a, dict):
        raise InputError(f"{where}: 'answer' must be an object")
    tr = Truth(
        pos_tol=a.get("tolerance_m", defaults.get("pos_tolerance_m")),
        time_tol=a.get("tolerance_s", defaults.get("time_tolerance_s")),
        none=bool(a.get("none", False)),
    )
    if "position" in a:
        pos = a["position"]
        items = pos if pos and isinstance(pos[0], list) else [pos]
        tr.positions = [(_num_list(p, (2, 3), where, "answer.position") + [0.0])[:3] for p in items]
    files = a.get("frames", [])
    if not isinstance(files, list) or not all(isinstance(f, str) for f in files):
        raise InputError(f"{where}: answer.frames must be a list of frame file names")
    for rng in a.get("frame_ranges", []):
        if not (isinstance(rng, list) and len(rng) == 2 and all(isinstance(f, str) for f in rng)):
            raise InputError(
                f"{where}: answer.frame_ranges items must be [first_file, last_file], got {rng!r}"
            )
        files = files + index.between(rng[0], rng[1], where)
    if files:
        tr.files = files
        tr.times = [index.time(f, where) for f in files]
        if qtype == "position" and not tr.positions:
            tr.positions = [list(index.pose(f, where).xyz) for f in files]
    if "time" in a:
        tr.rel_times = [float(a["time"])]
    if "time_unix" in a:
        tr.times = [float(a["time_unix"])]
    if "window" in a:
        tr.rel_window = _num_list(a["window"], (2,), where, "answer.window")
    if "yes" in a:
        tr.yes = bool(a["yes"])
    if "text" in a:
        tr.text = [a["text"]] if isinstance(a["text"], str) else [str(t) for t in a["text"]]
    if "duration_s" in a:
        tr.duration = float(a["duration_s"])
    needed = {
        "position": tr.positions,
        "time": tr.times or tr.rel_times or tr.rel_window,
        "frame": tr.times,
        "binary": tr.yes is not None,
        "text": tr.text,
        "duration": tr.duration is not None,
    }[qtype]
    if not needed and not tr.none:
        raise InputError(
            f"{where}: a {qtype} question needs an answer of its kind (see docs/evaluation.md, 'Datasets and their exact layouts')"
        )
    image = None
    if q.get("image"):
        image = (base / str(q["image"])).resolve()
        if not image.is_file():
            raise InputError(f"{where}: query image {image} not found")
    return Question(
        id=str(q.get("id", f"q{n}")),
        text=text.strip(),
        type=cast(EvalType, qtype),
        truth=tr,
        category=str(q.get("category", "")).lower(),
        horizon=str(q.get("horizon", "")),
        image=image,
    )


def load(
    path: str, fmt: str, queries: str | None = None, source_opts: dict[str, Any] | None = None, **_: Any
) -> list[Episode]:
    """One episode: the recording at `path` (format `fmt`) and the questions of `queries`."""
    qfile = Path(queries) if queries else (Path(path) if fmt == "queries" else None)
    if qfile is None:
        raise InputError(
            f"--dataset {fmt}:{path} needs --queries QUESTIONS.json (see docs/evaluation.md, 'Datasets and their exact layouts')"
        )
    try:
        doc = json.loads(read_text(qfile, what="question file"))
    except (OSError, ValueError) as e:  # ValueError: not UTF-8, not JSON
        raise InputError(f"{qfile}: cannot read JSON ({e})") from e
    if not isinstance(doc, dict) or not isinstance(doc.get("questions"), list):
        raise InputError(f"{qfile}: expected an object with a 'questions' list")
    if fmt == "queries":
        src = doc.get("source")
        if not isinstance(src, str) or ":" not in src:
            raise InputError(
                f'{qfile}: needs "source": "FORMAT:PATH" (e.g. tum:data/tum) when used as --dataset queries:'
            )
        fmt, _sep, rel = src.partition(":")
        path = str((qfile.parent / rel).resolve())
    if fmt not in SOURCE_FORMATS:
        raise InputError(f"unknown recording format {fmt!r}; choose one of {', '.join(SOURCE_FORMATS)}")
    rec = Path(path)
    if not rec.exists():
        raise InputError(f"recording {rec} does not exist")
    index = FrameIndex(rec)
    qs = [parse_question(q, n, qfile.parent, index, doc, str(qfile)) for n, q in enumerate(doc["questions"])]
    ids = [q.id for q in qs]
    dup = sorted({i for i in ids if ids.count(i) > 1})
    if dup:
        raise InputError(f"{qfile}: question ids repeat: {', '.join(dup)}")
    opts = dict(source_opts or {})
    name = f"{fmt}/{rec.name}"

    def frames() -> Any:
        from ...ingest.sources import open_source

        return open_source(str(rec), None if fmt == "bag" else fmt, **opts)

    return [
        Episode(
            id=name,
            dataset=fmt,
            key=f"{fmt}:{rec.resolve()}:{json.dumps(opts, sort_keys=True, default=str)}",
            frames=frames,
            questions=qs,
            t0=index.first_time(),
            frame_tol=doc.get("time_tolerance_s"),
            trajectory=sorted((index.times[f], p.x, p.y) for f, p in index.poses.items()),
            has_poses=bool(index.poses),
            frame_times=[t for t, _ in index.ordered()],
            frame_files=[f for _, f in index.ordered()],
            memory_path=rec if fmt == "memory" else None,
            pos_threshold=doc.get("pos_tolerance_m"),
            meta={"queries": str(qfile)},
        )
    ]


def _loader(fmt: str) -> Any:
    def load_format(path: str, **kw: Any) -> list[Episode]:
        return load(path, fmt, **kw)

    return load_format


for _fmt in (*SOURCE_FORMATS, "queries"):
    DATASETS.register(_fmt)(_loader(_fmt))
