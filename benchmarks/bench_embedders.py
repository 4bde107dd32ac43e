"""Text -> image retrieval quality and speed of the offline embedder designs on real TUM frames.

Ground truth: benchmarks/data/tum_labels.json (91 frames of TUM fr1_rpy labelled by eye with the
objects visible). For every design, each labelled object's query ("a computer keyboard", ...)
ranks the 91 frames; we report mean average precision (mAP) over all queries and over the
small-object queries (mug, game controller, mouse, telephone), mean precision@5, the expected AP of a
random ranking, and images/s of the whole embed_images call (tiling + one batched forward pass +
pooling) with torch limited to --threads threads. The metrics and the labels reader are
`ravenmem.eval.retrieval`, shared with `ravenmem eval study embedders` (which compares whole
embedders, text->image and image->image; this script compares the offline designs).

    PYTHONPATH=src python benchmarks/bench_embedders.py --threads 2
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))

from ravenmem.embed.offline import OfflineConfig, OfflineEmbedder  # noqa: E402
from ravenmem.eval.retrieval import (  # noqa: E402
    MIN_POSITIVES,
    average_precision,
    load_images,
    load_labels,
    summarize_direction,
    text_to_image,
)

DEFAULT_DATA = ROOT.parent / "shared" / "data" / "tum_fr1_rpy"
LABELS = ROOT / "benchmarks" / "data" / "tum_labels.json"


def evaluate(
    img_vecs: np.ndarray, txt_vecs: np.ndarray, truth: np.ndarray, small: np.ndarray
) -> dict[str, float]:
    """truth: (n_queries, n_images) bool; small: (n_queries,) bool, the small-object queries."""
    m = summarize_direction(text_to_image(img_vecs, txt_vecs, truth, k=5), small)
    return {"mAP": m["mAP"], "small": m["mAP_small"], "bal": (m["mAP"] + m["mAP_small"]) / 2, "P@5": m["P@k"]}


def load(data: Path) -> tuple[list[str], list[np.ndarray], list[str], list[str], np.ndarray, np.ndarray]:
    labels = load_labels(LABELS)
    objects = labels.objects(MIN_POSITIVES)
    truth = labels.truth(objects)
    small = np.array([o in labels.small for o in objects])
    images = load_images(labels, data / "rgb")
    return list(labels.frames), images, objects, [labels.queries[o] for o in objects], truth, small


def time_embed(
    emb: OfflineEmbedder, images: list[np.ndarray], batch: int, repeats: int
) -> tuple[float, float]:
    """Images per second (wall clock) of embed_images in batches of `batch`, and CPU seconds per
    image (median over repeats). On a shared machine the wall figure drops with other load; the
    CPU figure (all threads) moves much less."""
    emb.embed_images(images[:batch])  # warm-up
    rates, cpu = [], []
    for _ in range(repeats):
        t0, c0 = time.perf_counter(), time.process_time()
        for s in range(0, len(images), batch):
            emb.embed_images(images[s : s + batch])
        rates.append(len(images) / (time.perf_counter() - t0))
        cpu.append((time.process_time() - c0) / len(images))
    return statistics.median(rates), statistics.median(cpu)


def designs(base: OfflineConfig) -> list[OfflineConfig]:
    """The designs compared per tile layout (pools: the default fmax, plus plain max)."""
    out = [
        replace(base, design="conse", t=10, temp=1.0),
        replace(base, design="conse", t=100, temp=3.0),
        replace(base, design="ridge"),
        replace(base, design="mix", t=100, temp=3.0, w=0.3),
        replace(base, design="cls"),
        replace(base, design="hybrid", t=100, temp=3.0, w=0.3, a=0.7),
    ]
    if base.tiles > 1:
        out += [replace(c, pool="max") for c in out]
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--data", type=Path, default=DEFAULT_DATA)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--batch", type=int, default=8, help="images per embed_images call when timing")
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--layouts", default="1@224,5@224,6@224,10@224,5@192", help="tiles@res list")
    args = ap.parse_args()
    if not (args.data / "rgb").is_dir():
        sys.exit(f"error: {args.data}/rgb not found (TUM fr1_rpy); pass --data")

    import torch

    torch.set_num_threads(args.threads)
    names, images, objects, queries, truth, small = load(args.data)
    print(
        f"{len(names)} frames, {len(queries)} queries with >= {MIN_POSITIVES} positives: {', '.join(objects)}"
    )
    print(f"small objects: {', '.join(o for o, s in zip(objects, small) if s)}")
    print(f"torch threads={torch.get_num_threads()}, timing batch={args.batch}\n")

    rows = []
    outputs = {}
    for spec in args.layouts.split(","):
        tiles, res = (int(x) for x in spec.split("@"))
        emb = OfflineEmbedder(OfflineConfig(tiles=tiles, res=res))
        ips, cpu = time_embed(emb, images, args.batch, args.repeats)
        print(f"tiles{tiles}@{res}: {ips:.1f} images/s wall, {cpu * 1000:.0f} ms CPU per image")
        logits, feats = emb.classify(images)
        outputs[(tiles, res)] = (emb, logits, feats)
        for cfg in designs(emb.config):
            m = evaluate(emb.vectors(logits, feats, cfg), emb.embed_texts(queries, cfg), truth, small)
            rows.append((cfg, m, ips))
    print(f"{'embedder name':<72} {'dim':>5} {'mAP':>6} {'small':>6} {'bal':>6} {'P@5':>6} {'img/s':>6}")
    for cfg, m, ips in sorted(rows, key=lambda r: -r[1]["bal"]):
        print(
            f"{cfg.name:<72} {cfg.dim:5d} {m['mAP']:6.3f} {m['small']:6.3f} {m['bal']:6.3f} {m['P@5']:6.3f} {ips:6.1f}"
        )
    prevalence = truth.mean(axis=1)
    print(
        f"{'random ranking (expected AP = fraction of positives)':<72} {'':5} {prevalence.mean():6.3f} {prevalence[small].mean():6.3f}"
    )
    print("bal = (mAP + small) / 2, the selection criterion: all objects and small objects count equally")

    best = max(rows, key=lambda r: r[1]["bal"])[0]
    emb, logits, feats = outputs[(best.tiles, best.res)]
    sims = emb.embed_texts(queries, best) @ emb.vectors(logits, feats, best).T
    print(f"\nper-query AP of the best ({best.name}):")
    for q, s, t in zip(queries, sims, truth):
        print(
            f"  {q:<22} positives {int(t.sum()):3d}/{len(t)}  AP {average_precision(s, t):.3f}  chance {t.mean():.3f}"
        )


if __name__ == "__main__":
    main()
