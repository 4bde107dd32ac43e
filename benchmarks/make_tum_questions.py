"""Write benchmarks/data/tum_objects.json: labelled questions about the TUM fr1/rpy desk in the
evaluation's own format (docs/evaluation.md), built from the hand labels.

Sources: benchmarks/data/tum_labels.json (every 8th frame labelled by eye with the objects in
view) and the 35 questions of benchmarks/bench_reasoner.py (first/last sightings, presence,
durations; absent objects were checked absent on contact sheets). Made from them:

- frame questions "Where did you see <object>?" for every object labelled in >= 2 frames:
  right when the answer's frame is within half a label step (0.14 s) of a labelled frame that
  shows it (the object is in view there);
- time questions (first/last sightings): the window between the last labelled frame without
  the object and the first with it (mirrored for last), 1 s of tolerance as bench_reasoner;
- yes/no questions as bench_reasoner; durations: the labelled time in view, +-50 %.

    python benchmarks/make_tum_questions.py        # rewrites the file (deterministic)
"""

from __future__ import annotations

import json
import sys
from collections import defaultdict
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))

from bench_reasoner import LABEL_STEP, QUESTIONS  # noqa: E402

DATA = ROOT.parent / "shared" / "data" / "tum_fr1_rpy"
LABELS = ROOT / "benchmarks" / "data" / "tum_labels.json"
OUT = ROOT / "benchmarks" / "data" / "tum_objects.json"


def main() -> None:
    doc = json.loads(LABELS.read_text(encoding="utf-8"))
    names = sorted(p.name for p in (DATA / "rgb").glob("*.jpg"))
    times = [float(n[:-4]) for n in names]
    seen: dict[str, list[int]] = defaultdict(list)
    for name, objs in doc["frames"].items():
        for o in objs:
            seen[o].append(names.index(name))
    dt = (times[-1] - times[0]) / (len(times) - 1)
    qs: list[dict[str, object]] = []
    for obj, query in sorted(doc["queries"].items()):
        idx = sorted(seen.get(obj, []))
        if len(idx) < 2:
            continue
        qs.append(
            {
                "id": f"where-{obj}",
                "question": f"Where did you see {query}?",
                "type": "frame",
                "category": "small object" if obj in doc.get("small_objects", []) else "object",
                "answer": {
                    "frames": [f"rgb/{names[i]}" for i in idx],
                    "tolerance_s": round(dt * LABEL_STEP / 2, 3),
                },
            }
        )
    for text, kind, label in QUESTIONS:
        rel = [t - times[0] for t in times]
        if kind in ("yes", "no"):
            qs.append(
                {
                    "id": f"{kind}-{label or text.split()[-1].rstrip('?')}",
                    "question": text,
                    "type": "binary",
                    "category": "presence",
                    "answer": {"yes": kind == "yes"},
                }
            )
            continue
        assert label is not None
        idx = sorted(seen[label])
        if kind == "duration":
            truth = len(idx) * LABEL_STEP * dt
            qs.append(
                {
                    "id": f"duration-{label}",
                    "question": text,
                    "type": "duration",
                    "category": "duration",
                    "answer": {"duration_s": round(truth, 3), "tolerance_s": round(truth / 2, 3)},
                }
            )
            continue
        if kind == "first":
            lo, hi = rel[max(0, idx[0] - LABEL_STEP)], rel[idx[0]]
        else:
            lo, hi = rel[idx[-1]], rel[min(len(rel) - 1, idx[-1] + LABEL_STEP)]
        qs.append(
            {
                "id": f"{kind}-{label}",
                "question": text,
                "type": "time",
                "category": "temporal",
                "answer": {"window": [round(lo, 3), round(hi, 3)], "tolerance_s": 1.0},
            }
        )
    out = {
        "name": "TUM RGB-D fr1/rpy desk: questions made from the hand labels (benchmarks/make_tum_questions.py)",
        "source": "tum:../../../shared/data/tum_fr1_rpy",
        "notes": (
            "Frame questions: the answer's frame within half a label step of a labelled frame showing "
            "the object. Times are seconds from the first frame. Generated; do not edit by hand."
        ),
        "questions": qs,
    }
    OUT.write_text(json.dumps(out, indent=1) + "\n", encoding="utf-8")
    kinds: dict[str, int] = defaultdict(int)
    for q in qs:
        kinds[str(q["type"])] += 1
    print(f"wrote {OUT}: {len(qs)} questions ({dict(kinds)})")


if __name__ == "__main__":
    main()
