"""Offline reasoner vs the plain embedder-only baseline (and random) on real TUM frames.

The memory: TUM fr1_rpy ingested with the offline embedder and the default keyframe rules (no
OCR; `--keyframes stride=3` gives the every-3rd-frame memory measured before the defaults). The
questions below are hand-written; their ground truth comes from benchmarks/data/tum_labels.json
(every 8th frame labelled by eye with the objects visible; the first/last sightings used here
were checked again by looking at the frames around them). Absent objects were checked absent on
contact sheets of the whole recording.

Scoring: time questions are right when the answer's time falls between the last labelled frame
without the object and the first with it ("first"; mirrored for "last"), widened by --tol
seconds. Yes/no questions must match. Duration questions are right within a factor of 2 of the
labelled visible time. (Positions are not scored: the camera only rotates in place here, so any
memory's position is within centimetres of the truth.)

    PYTHONPATH=src python benchmarks/bench_reasoner.py [--keyframes default|stride=3] [--threads 2]
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from collections import defaultdict
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))

import ravenmem  # noqa: E402
from ravenmem.agent import create_method  # noqa: E402
from ravenmem.agent.schema import Answer  # noqa: E402

DATA = ROOT.parent / "shared" / "data" / "tum_fr1_rpy"
LABELS = ROOT / "benchmarks" / "data" / "tum_labels.json"
LABEL_STEP = 8  # labels exist for every 8th frame

# (question, kind, label): kind first/last -> time, yes/no -> binary, duration
QUESTIONS: list[tuple[str, str, str | None]] = [
    ("When did I first see the person?", "first", "person"),
    ("When did I first see the floor lamp?", "first", "lamp"),
    ("When did I first see the game controller?", "first", "gamepad"),
    ("When did I first see an office chair?", "first", "chair"),
    ("When did I first see the trash can?", "first", "trash_can"),
    ("When did I first see the telephone?", "first", "phone"),
    ("When did I first notice the coffee mug?", "first", "mug"),
    ("When did I last see the game controller?", "last", "gamepad"),
    ("When did I last see the floor lamp?", "last", "lamp"),
    ("When did I last see the trash can?", "last", "trash_can"),
    ("When did I last see the computer mouse?", "last", "mouse"),
    ("When did I last see the keyboard?", "last", "keyboard"),
    ("When did I last see the laptop?", "last", "laptop"),
    ("When did I last see a book?", "last", "book"),
    ("Did I see a trash can?", "yes", "trash_can"),
    ("Was there a laptop?", "yes", "laptop"),
    ("Did I see a game controller?", "yes", "gamepad"),
    ("Is there a floor lamp?", "yes", "lamp"),
    ("Did I see a computer keyboard?", "yes", "keyboard"),
    ("Did I see a coffee mug?", "yes", "mug"),
    ("Did I see a telephone?", "yes", "phone"),
    ("Did I see a bicycle?", "no", None),
    ("Was there a piano?", "no", None),
    ("Did I see a dog?", "no", None),
    ("Did I see a car?", "no", None),
    ("Is there a bathtub?", "no", None),
    ("Did I see an umbrella?", "no", None),
    ("Did I see a refrigerator?", "no", None),
    ("Was there a sofa?", "no", None),
    ("Did I see a microwave?", "no", None),
    ("Did I see a cat?", "no", None),
    ("Did I see a guitar?", "no", None),
    ("How long did I see the floor lamp?", "duration", "lamp"),
    ("How long did I see the game controller?", "duration", "gamepad"),
    ("How long did I see the trash can?", "duration", "trash_can"),
]


def load_truth() -> tuple[list[float], dict[str, list[int]]]:
    """Frame times (every frame) and, per label, the frame indices of labelled frames showing it."""
    names = sorted(p.name for p in (DATA / "rgb").glob("*.jpg"))
    times = [float(n[:-4]) for n in names]
    labels = json.loads(LABELS.read_text())["frames"]
    seen: dict[str, list[int]] = defaultdict(list)
    for name, objs in labels.items():
        for o in objs:
            seen[o].append(names.index(name))
    return times, {k: sorted(v) for k, v in seen.items()}


def correct(
    ans: Answer, kind: str, label: str | None, times: list[float], seen: dict[str, list[int]], tol: float
) -> bool:
    if kind in ("yes", "no"):
        return ans.yes is (kind == "yes")
    assert label is not None
    idx = seen[label]
    dt = (times[-1] - times[0]) / (len(times) - 1)
    if kind == "duration":
        truth = len(idx) * LABEL_STEP * dt
        return ans.duration is not None and truth / 2 <= ans.duration <= truth * 2
    if ans.time is None:
        return False
    if kind == "first":
        lo, hi = times[max(0, idx[0] - LABEL_STEP)], times[idx[0]]
    else:
        lo, hi = times[idx[-1]], times[min(len(times) - 1, idx[-1] + LABEL_STEP)]
    return lo - tol <= ans.time <= hi + tol


def score(
    method: object, times: list[float], seen: dict[str, list[int]], tol: float
) -> dict[str, list[bool]]:
    per: dict[str, list[bool]] = defaultdict(list)
    for q, kind, label in QUESTIONS:
        ok = correct(method.ask(q), kind, label, times, seen, tol)  # type: ignore[attr-defined]
        per[{"first": "time", "last": "time", "yes": "binary", "no": "binary"}.get(kind, kind)].append(ok)
        per["all"].append(ok)
    return per


def sweep(mem: object, times: list[float], seen: dict[str, list[int]], tol: float) -> None:
    """How much the offline reasoner's answers depend on its two thresholds."""
    from ravenmem.agent import OfflineReasoner, OfflineReasonerConfig

    for quantile in (0.8, 0.9):
        for margin in (1.0, 0.85, 0.75, 0.6, 0.5):
            r = OfflineReasoner(
                mem, config=OfflineReasonerConfig(temporal_margin=margin, decoy_quantile=quantile)
            )  # type: ignore[arg-type]
            per = score(r, times, seen, tol)
            print(
                f"decoy_quantile {quantile} temporal_margin {margin:4}: "
                + "  ".join(f"{g} {sum(v)}/{len(v)}" for g, v in per.items()),
                flush=True,
            )


def build(path: Path, keyframes: str) -> None:
    from ravenmem.ingest.keyframes import KeyframeConfig
    from ravenmem.ingest.pipeline import ingest
    from ravenmem.ingest.tum import TumSource

    t = time.perf_counter()
    with ravenmem.create(path, embedder="offline", ocr=False) as mem:
        rep = ingest(
            TumSource(DATA, depth=False), mem, keyframes=KeyframeConfig.from_spec(keyframes), progress=False
        )
    print(f"built {path}: {rep.kept} memories in {time.perf_counter() - t:.0f} s", file=sys.stderr)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument(
        "--keyframes", default="default", help="keyframe rules of the memory built (e.g. stride=3)"
    )
    ap.add_argument("--memory", type=Path, help="memory folder (default: one per --keyframes under /tmp)")
    ap.add_argument("--tol", type=float, default=1.0, help="seconds of slack on time answers")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--methods", default="offline,embedder-only,random")
    ap.add_argument("--verbose", action="store_true")
    ap.add_argument("--sweep", action="store_true", help="offline reasoner over a grid of its two thresholds")
    args = ap.parse_args()
    if not (DATA / "rgb.txt").exists():
        sys.exit(f"TUM data not found at {DATA}")
    os.environ["RAVENMEM_THREADS"] = str(args.threads)  # the offline embedder's onnxruntime threads
    if args.memory is None:
        slug = "".join(c if c.isalnum() else "_" for c in args.keyframes)
        args.memory = Path(f"/tmp/ravenmem_bench_tum_{slug}.mem")
    if not (args.memory / "memory.json").exists():
        build(args.memory, args.keyframes)
    times, seen = load_truth()
    with ravenmem.open(args.memory) as mem:
        print(f"memory: {mem.count()} memories, embedder {mem.manifest.embedder}")
        if args.sweep:
            sweep(mem, times, seen, args.tol)
            return
        results: dict[str, dict[str, list[bool]]] = {}
        for name in args.methods.split(","):
            method = create_method(name, mem, seed=0)
            per: dict[str, list[bool]] = defaultdict(list)
            t0 = time.perf_counter()
            method.ask("Did I see a keyboard?")  # warm-up: model load, decoy calibration
            warm = time.perf_counter() - t0
            t0 = time.perf_counter()
            for q, kind, label in QUESTIONS:
                ans = method.ask(q)
                ok = correct(ans, kind, label, times, seen, args.tol)
                group = {"first": "time", "last": "time", "yes": "binary", "no": "binary"}.get(kind, kind)
                per[group].append(ok)
                per["all"].append(ok)
                if args.verbose:
                    rel = f"{ans.time - times[0]:6.2f}s" if ans.time is not None else "   -   "
                    print(
                        f"  {name:14s} {'OK ' if ok else 'BAD'} {q:45s} t={rel} yes={ans.yes} dur={ans.duration}"
                    )
            per_q = (time.perf_counter() - t0) / len(QUESTIONS)
            results[name] = per
            print(
                f"{name:14s} "
                + "  ".join(f"{g} {sum(v)}/{len(v)} ({100 * sum(v) / len(v):.0f}%)" for g, v in per.items())
                + f"  | {per_q * 1000:.0f} ms/question (first call {warm:.1f} s)"
            )


if __name__ == "__main__":
    main()
