"""Keyframe rules and diverse results on the real TUM fr1_rpy frames: what is kept, what is lost.

Every one of the 723 frames is embedded once with the default offline embedder (cached in
--cache), then each keyframe rule is replayed through `Keyframer` on the real poses and
embeddings. Ground truth: benchmarks/data/tum_labels.json (every 8th frame labelled by eye with
the objects visible); a kept frame takes the labels of the nearest labelled frame (at most 4
frames = 0.13 s away). Columns:

- kept: keyframes out of 723 frames (and frames per keyframe);
- sightings: runs of consecutive labelled frames showing an object (76) that still have a
  keyframe inside them;
- first/last: mean error (s) of the first and last keyframe showing each object against the
  first and last labelled sighting (what "when did I first/last see X" needs), and the share of
  those times off by more than 1 s (a missing object counts the whole recording);
- mAP / top-1 / P@5: the labelled queries ranking the kept frames (mAP's chance level changes
  with the set, so compare top-1 and P@5 across rows).

Then the diverse-results rule (ravenmem.memory.diversity) on every frame and on the default keyframes:
P@5 and distinct views in the top 5, with and without it.

    PYTHONPATH=src python benchmarks/bench_keyframes.py [--threads 2] [--sheet kept.png]
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))

from ravenmem.ingest.keyframes import KeyframeConfig, Keyframer, describe  # noqa: E402
from ravenmem.memory import diversity  # noqa: E402
from ravenmem.types import Frame, Hit, MemoryRecord  # noqa: E402

DATA = ROOT.parent / "shared" / "data" / "tum_fr1_rpy"
LABELS = ROOT / "benchmarks" / "data" / "tum_labels.json"
STEP = 8  # labels exist for every 8th frame
MIN_POSITIVES = 3


def embed_all(cache: Path, threads: int) -> dict[str, np.ndarray]:
    """Times, poses and default-embedder vectors of every frame (cached by embedder name)."""
    from ravenmem.embed import create_embedder
    from ravenmem.ingest.tum import TumSource

    emb = create_embedder(f"offline:threads={threads}")
    if cache.exists():
        z = dict(np.load(cache, allow_pickle=False))
        if str(z["embedder"]) == emb.name:
            return z
    src = TumSource(DATA, depth=False, pose_match="interpolate", max_gap=0.2)  # all 723 frames posed
    rows, vecs, batch = [], [], []
    t0 = time.perf_counter()
    for f in src:
        assert f.pose is not None and f.pose.quat is not None
        rows.append([f.t, f.pose.x, f.pose.y, f.pose.z, *f.pose.quat])
        batch.append(f.image)
        if len(batch) == 16:
            vecs.append(emb.embed_images(batch))
            batch = []
    if batch:
        vecs.append(emb.embed_images(batch))
    print(f"embedded {len(rows)} frames in {time.perf_counter() - t0:.0f} s", file=sys.stderr)
    z = {"rows": np.asarray(rows), "emb": np.vstack(vecs), "embedder": np.asarray(emb.name)}
    np.savez(cache, **z)
    return z


class Truth:
    """Labels of every 8th frame, propagated to the nearest labelled frame."""

    def __init__(self, n: int) -> None:
        doc = json.loads(LABELS.read_text())
        names = sorted(p.name for p in (DATA / "rgb").glob("*.jpg"))
        assert len(names) == n, f"{len(names)} images, {n} frames"
        self.labels = {names.index(k): set(v) for k, v in doc["frames"].items()}
        self.labelled = sorted(self.labels)
        self.objects = [
            o for o in doc["queries"] if sum(o in v for v in self.labels.values()) >= MIN_POSITIVES
        ]
        self.queries = [doc["queries"][o] for o in self.objects]
        self.sightings = []
        for o in self.objects:
            run: list[int] = []
            for i in [*self.labelled, -1]:
                if i >= 0 and o in self.labels[i]:
                    run.append(i)
                elif run:
                    self.sightings.append((o, run[0], run[-1]))
                    run = []

    def of(self, i: int) -> set[str]:
        j = min(max(round(i / STEP) * STEP, self.labelled[0]), self.labelled[-1])
        return self.labels[j]


def ap(scores: np.ndarray, rel: np.ndarray) -> float:
    if not rel.any():
        return 0.0
    r = rel[np.argsort(-scores, kind="stable")]
    return float((np.cumsum(r)[r] / (np.flatnonzero(r) + 1)).mean())


def select(cfg: KeyframeConfig, frames: list[Frame], emb: np.ndarray) -> list[int]:
    kf = Keyframer(cfg)
    return [i for i, f in enumerate(frames) if kf.pre(f) is None and kf.post(emb[i]) is None]


def evaluate(
    kept: list[int], truth: Truth, t: np.ndarray, emb: np.ndarray, txt: np.ndarray
) -> dict[str, float]:
    rel = np.array([[o in truth.of(i) for i in kept] for o in truth.objects])
    sims = txt @ emb[kept].T
    order = np.argsort(-sims, axis=1, kind="stable")
    errs = []
    for o in truth.objects:
        seen = [i for i in truth.labelled if o in truth.labels[i]]
        shown = [i for i in kept if o in truth.of(i)]
        if not shown:
            errs += [t[-1] - t[0]] * 2
            continue
        errs += [abs(t[shown[0]] - t[seen[0]]), abs(t[shown[-1]] - t[seen[-1]])]
    return {
        "kept": len(kept),
        "sightings": float(
            np.mean([any(a - STEP // 2 <= i <= b + STEP // 2 for i in kept) for _, a, b in truth.sightings])
        ),
        "fl": float(np.mean(errs)),
        "fl_bad": float(np.mean(np.array(errs) > 1.0)),
        "mAP": float(np.mean([ap(s, r) for s, r in zip(sims, rel)])),
        "top1": float(np.mean([r[o[0]] for r, o in zip(rel, order)])),
        "P@5": float(np.mean([r[o[:5]].mean() for r, o in zip(rel, order)])),
    }


def diverse_eval(
    kept: list[int],
    records: list[MemoryRecord],
    truth: Truth,
    emb: np.ndarray,
    txt: np.ndarray,
    diverse: bool,
) -> tuple[float, float]:
    """(P@5, distinct views in the top 5) over the labelled queries."""
    p5, distinct = [], []
    for q, o in zip(txt, truth.objects):
        sims = emb[kept] @ q
        ranked = [Hit(records[kept[j]], float(sims[j])) for j in np.argsort(-sims, kind="stable")]
        top = diversity.pick(ranked, 5) if diverse else ranked[:5]
        p5.append(np.mean([o in truth.of(h.memory.id) for h in top]))
        distinct.append(len(diversity.pick(top, 5)))
    return float(np.mean(p5)), float(np.mean(distinct))


def main() -> None:
    ap_ = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap_.add_argument("--cache", type=Path, default=Path("/tmp/ravenmem_bench_tum_embeddings.npz"))
    ap_.add_argument("--threads", type=int, default=2)
    ap_.add_argument("--sheet", type=Path, help="write a contact sheet of the default keyframes here")
    a = ap_.parse_args()
    if not (DATA / "rgb.txt").exists():
        sys.exit(f"TUM data not found at {DATA}")
    from ravenmem.embed import create_embedder
    from ravenmem.types import Pose

    z = embed_all(a.cache, a.threads)
    rows, emb = z["rows"], z["emb"]
    t = rows[:, 0]
    img = np.zeros((2, 2, 3), np.uint8)
    poses = [Pose.from_quaternion(*r[1:8]) for r in rows]
    frames = [Frame(img, float(r[0]), p, index=i) for i, (r, p) in enumerate(zip(rows, poses))]
    records = [MemoryRecord(id=i, t=float(r[0]), pose=p) for i, (r, p) in enumerate(zip(rows, poses))]
    truth = Truth(len(frames))
    txt = create_embedder("offline").embed_texts(truth.queries)
    default = KeyframeConfig()
    rules: list[tuple[str, list[int]]] = [
        ("every frame", list(range(len(frames)))),
        ("stride 3", list(range(0, len(frames), 3))),
        ("stride 15 (about the default's count, no rule)", list(range(0, len(frames), 15))),
    ]
    grid = [("default: " + describe(default), default)]
    for rot in (10, 15, 20, 25, 30):
        for sim in (None, 0.93, 0.95, 0.97, 0.98):
            if (rot, sim) != (15, 0.97):
                grid.append(
                    (
                        f"turned {rot} deg, cosine <= {sim}",
                        replace(default, min_rotation=math.radians(rot), max_similarity=sim),
                    )
                )
    for window in (3.0, 10.0):
        name = f"as default, novelty against EVERY keyframe of the last {window:g} s"
        rules.append((name, select_window(default, window, frames, emb)))
    rules += [(name, select(cfg, frames, emb)) for name, cfg in grid]
    print(
        f"{len(frames)} frames, {len(truth.objects)} labelled queries, {len(truth.sightings)} object sightings"
    )
    print(
        f"{'rule':<100} {'kept':>5} {'fr/kf':>6} {'sight.':>6} {'f/l s':>6} {'>1s':>5} {'mAP':>6} {'top1':>5} {'P@5':>5}"
    )
    for name, kept in rules:
        m = evaluate(kept, truth, t, emb, txt)
        print(
            f"{name:<100} {m['kept']:5d} {len(frames) / m['kept']:6.1f} {m['sightings']:6.2f} {m['fl']:6.2f} "
            f"{m['fl_bad']:5.2f} {m['mAP']:6.3f} {m['top1']:5.2f} {m['P@5']:5.2f}"
        )
    kept_default = select(default, frames, emb)
    s = diversity.SAME_VIEW
    print(
        f"\ndiverse results (same view: within {s.seconds:g} s, {s.metres:g} m and {s.degrees:g} deg), top 5:"
    )
    for name, kept in (("every frame", list(range(len(frames)))), ("default keyframes", kept_default)):
        for div in (False, True):
            p5, distinct = diverse_eval(kept, records, truth, emb, txt, div)
            print(f"  {name:<18} diverse={div!s:<5}  P@5 {p5:.2f}  distinct views {distinct:.2f} of 5")
    if a.sheet:
        contact_sheet(a.sheet, kept_default, t)
        print(f"contact sheet of the {len(kept_default)} default keyframes: {a.sheet}")


def select_window(cfg: KeyframeConfig, window: float, frames: list[Frame], emb: np.ndarray) -> list[int]:
    """The rejected alternative: novelty against every keyframe kept in the last `window` s."""
    kf = Keyframer(replace(cfg, max_similarity=None))
    assert cfg.max_similarity is not None
    kept: list[int] = []
    for i, f in enumerate(frames):
        if kf.pre(f) is not None:
            continue
        recent = [j for j in kept if f.t - frames[j].t <= window]
        if recent and float(np.max(emb[recent] @ emb[i])) > cfg.max_similarity:
            continue
        kept.append(i)
    return kept


def contact_sheet(path: Path, kept: list[int], t: np.ndarray, cols: int = 8, w: int = 200) -> None:
    from PIL import Image, ImageDraw

    names = sorted((DATA / "rgb").glob("*.jpg"))
    h = w * 3 // 4
    sheet = Image.new("RGB", (cols * w, -(-len(kept) // cols) * h), "white")
    draw = ImageDraw.Draw(sheet)
    for n, i in enumerate(kept):
        x, y = (n % cols) * w, (n // cols) * h
        sheet.paste(Image.open(names[i]).convert("RGB").resize((w, h)), (x, y))
        draw.rectangle([x, y, x + 70, y + 11], fill="black")
        draw.text((x + 2, y), f"{i} {t[i] - t[0]:.1f}s", fill="yellow")
    sheet.save(path)


if __name__ == "__main__":
    main()
