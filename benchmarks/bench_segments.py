"""Segment-level embeddings searched coarse-to-fine, against frame-level search: quality and cost.

The paper's Figure 1 shows frame- and segment-level entries. A *segment* here is a run of
consecutive keyframes of one place (each frame's cosine to the run's mean stays above a
threshold, at most --max-len frames); its embedding is the normalised mean of its frames'.
Coarse-to-fine search scores every segment, then the frames of the best --probe segments, and
returns the best k of those frames.

A. Quality on real frames: the 91 hand-labelled TUM fr1/rpy frames (benchmarks/data/
   tum_labels.json, every frame judged) embedded by the offline embedder, segmented in time
   order. Per object (seen in >= 3 frames): text->image and image->image AP over the full
   ranking (frame level: by frame score; coarse-to-fine: segments by pooled score, frames within
   by frame score), and recall@10 of the relevant frames among the k = 10 results with
   --probe segments probed. The metrics are `ravenmem.eval.retrieval`'s.

B. Cost at scale: --n synthetic memories (dim 384): bench_store's stream (visits of 100-800
   frames drifting around a place's look, places revisited; --data store, the default) or
   planted segments (a random direction per segment, frames = direction + noise, lengths
   1..2L: --data planted, made for segments); queries = a stored frame plus noise.
   Side by side in one run: exact frame-level scoring (numpy, every vector), coarse-to-fine
   (numpy: every segment vector + the probed segments' frames) and a FAISS IVF over the frames
   (what the local store uses above 50k memories; nlist 4 sqrt(n), nprobe 32). Reported:
   vectors scored per query, latency p50, recall@10 against exact.

    OMP_NUM_THREADS=2 nice -n 19 python benchmarks/bench_segments.py --n 1000000
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))

from ravenmem.eval.retrieval import (  # noqa: E402
    MIN_POSITIVES,
    average_precision,
    load_images,
    load_labels,
)

DATA = ROOT.parent / "shared" / "data" / "tum_fr1_rpy"
LABELS = ROOT / "benchmarks" / "data" / "tum_labels.json"


def segment(emb: np.ndarray, min_sim: float, max_len: int) -> np.ndarray:
    """Segment id per frame (frames in time order): a frame joins the current run while its
    cosine to the run's mean embedding is >= min_sim and the run is shorter than max_len."""
    seg = np.zeros(len(emb), np.int64)
    total = emb[0].astype(np.float64).copy()
    length, sid = 1, 0
    for i in range(1, len(emb)):
        mean = total / np.linalg.norm(total)
        if length < max_len and float(emb[i] @ mean) >= min_sim:
            total += emb[i]
            length += 1
        else:
            sid += 1
            total, length = emb[i].astype(np.float64).copy(), 1
        seg[i] = sid
    return seg


def pooled(emb: np.ndarray, seg: np.ndarray) -> np.ndarray:
    out = np.zeros((int(seg.max()) + 1, emb.shape[1]), np.float64)
    np.add.at(out, seg, emb)
    out /= np.linalg.norm(out, axis=1, keepdims=True)
    return out.astype(np.float32)


def coarse_order(q: np.ndarray, emb: np.ndarray, seg: np.ndarray, pool: np.ndarray) -> np.ndarray:
    """The full coarse-to-fine ranking: segments by pooled score, frames within by frame score."""
    seg_rank = np.empty(len(pool), np.int64)
    seg_rank[np.argsort(-(pool @ q), kind="stable")] = np.arange(len(pool))
    return np.lexsort((-(emb @ q), seg_rank[seg]))


def coarse_topk(
    q: np.ndarray, emb: np.ndarray, members: list[np.ndarray], pool: np.ndarray, probe: int, k: int
) -> tuple[np.ndarray, int]:
    """k results of coarse-to-fine search with `probe` segments; and the vectors scored."""
    s = pool @ q
    top = np.argpartition(-s, min(probe, len(s) - 1))[:probe] if probe < len(s) else np.arange(len(s))
    cand = np.concatenate([members[i] for i in top])
    fs = emb[cand] @ q
    best = np.argsort(-fs)[:k]
    return cand[best], len(pool) + len(cand)


def ap_of_order(order: np.ndarray, relevant: np.ndarray) -> float:
    scores = np.empty(len(order), np.float64)
    scores[order] = -np.arange(len(order), dtype=np.float64)
    return average_precision(scores, relevant)


def members_of(seg: np.ndarray) -> list[np.ndarray]:
    order = np.argsort(seg, kind="stable")
    bounds = np.flatnonzero(np.diff(seg[order])) + 1
    return np.split(order, bounds)


# ------------------------------------------------------------------------------------ A. quality
def quality(cache_dir: Path, probe: int, k: int) -> None:
    from ravenmem.embed.base import create_embedder
    from ravenmem.eval.cache import CachingEmbedder

    labels = load_labels(LABELS)
    objects = labels.objects(MIN_POSITIVES)
    truth = labels.truth(objects)
    names = list(labels.frames)
    assert names == sorted(names), "labelled frames must be in time order"
    emb_model = CachingEmbedder(create_embedder("offline"), cache_dir / "embeddings")
    img = np.asarray(emb_model.embed_images(load_images(labels, DATA / "rgb")), np.float32)
    txt = np.asarray(emb_model.embed_texts([labels.queries[o] for o in objects]), np.float32)
    emb_model.close()
    print(
        f"A. quality: {len(names)} labelled TUM frames, {len(objects)} objects, offline embedder; "
        f"recall@{k} with {probe} segments probed"
    )
    print(
        f"{'segmentation':32} {'segs':>5} {'t->i mAP':>9} {'i->i mAP':>9} {'t->i R@k':>9} {'i->i R@k':>9} {'scored':>7}"
    )

    def row(label: str, seg: np.ndarray | None) -> None:
        t_ap, i_ap, t_rk, i_rk, scored = [], [], [], [], []
        pool = pooled(img, seg) if seg is not None else None
        members = members_of(seg) if seg is not None else None
        for o, tr in enumerate(truth):
            q = txt[o]
            if seg is None:
                order = np.argsort(-(img @ q), kind="stable")
                top, n_sc = order[:k], len(img)
            else:
                assert pool is not None and members is not None
                order = coarse_order(q, img, seg, pool)
                top, n_sc = coarse_topk(q, img, members, pool, probe, k)
            t_ap.append(ap_of_order(order, tr))
            t_rk.append(tr[top].sum() / min(k, tr.sum()))
            scored.append(n_sc)
            aps, rks = [], []
            for f in np.flatnonzero(tr):  # image -> image: the other frames showing the object
                others = np.arange(len(tr)) != f
                q = img[f]
                if seg is None:
                    order = np.argsort(-(img @ q), kind="stable")
                    top = order[: k + 1]
                else:
                    assert pool is not None and members is not None
                    order = coarse_order(q, img, seg, pool)
                    top, _ = coarse_topk(q, img, members, pool, probe, k + 1)
                order = order[others[order]]
                keep = np.flatnonzero(others)
                remap = -np.ones(len(tr), np.int64)
                remap[keep] = np.arange(len(keep))
                aps.append(ap_of_order(remap[order], tr[others]))
                top = top[top != f][:k]
                rks.append(tr[top].sum() / min(k, tr.sum() - 1))
            i_ap.append(float(np.nanmean(aps)))
            i_rk.append(float(np.mean(rks)))
        n_seg = "-" if seg is None else str(int(seg.max()) + 1)
        print(
            f"{label:32} {n_seg:>5} {np.nanmean(t_ap):9.3f} {np.nanmean(i_ap):9.3f} "
            f"{np.mean(t_rk):9.3f} {np.mean(i_rk):9.3f} {np.mean(scored):7.1f}",
            flush=True,
        )

    row("frame level (exact)", None)
    for max_len in (2, 4, 8):
        row(f"fixed length {max_len}", segment(img, -1.0, max_len))
    for sim in (0.9, 0.8, 0.7):
        seg = segment(img, sim, 16)
        row(f"adaptive cos >= {sim} (<= 16)", seg)


def quality_all_frames(cache_dir: Path, probe: int, k: int) -> None:
    """The same on all 720 posed frames (real segment lengths): each frame takes the labels of
    the nearest labelled frame (labels every 8th frame, so +-4 frames, 0.13 s)."""
    from ravenmem.embed.base import create_embedder
    from ravenmem.eval.cache import CachingEmbedder
    from ravenmem.ingest.tum import TumSource

    labels = load_labels(LABELS)
    objects = labels.objects(MIN_POSITIVES)
    lab_t = np.array([float(f[:-4]) for f in labels.frames])
    lab_truth = labels.truth(objects)
    frames = [f for f in TumSource(DATA, depth=False) if f.pose is not None]
    emb_model = CachingEmbedder(create_embedder("offline"), cache_dir / "embeddings")
    img = np.concatenate(
        [
            np.asarray(emb_model.embed_images([f.image for f in frames[s : s + 32]]), np.float32)
            for s in range(0, len(frames), 32)
        ]
    )
    txt = np.asarray(emb_model.embed_texts([labels.queries[o] for o in objects]), np.float32)
    emb_model.close()
    ft = np.array([f.t for f in frames])
    near = np.abs(ft[:, None] - lab_t[None, :]).argmin(1)
    truth = lab_truth[:, near]
    judged = np.abs(ft - lab_t[near]) < 1e-3  # the labelled frames themselves
    print(
        f"\nA2. all {len(frames)} posed frames searched; text->image. mAP and R@k: every frame takes the "
        f"labels of the nearest labelled frame; mAP exact: the ranking of the {judged.sum()} labelled "
        "frames alone (the others removed from it)"
    )
    print(f"{'segmentation':32} {'segs':>5} {'mAP':>7} {'R@k':>7} {'mAP exact':>10} {'scored':>7}")
    for label, seg in (
        [("frame level (exact)", None)]
        + [(f"fixed length {n}", segment(img, -1.0, n)) for n in (4, 8, 16)]
        + [(f"adaptive cos >= {c} (<= 32)", segment(img, c, 32)) for c in (0.9, 0.85, 0.8)]
    ):
        aps, rks, exact, scored = [], [], [], []
        pool = pooled(img, seg) if seg is not None else None
        members = members_of(seg) if seg is not None else None
        idx_judged = -np.ones(len(img), np.int64)
        idx_judged[judged] = np.arange(judged.sum())
        for o, tr in enumerate(truth):
            q = txt[o]
            if seg is None:
                order = np.argsort(-(img @ q), kind="stable")
                top, n_sc = order[:k], len(img)
            else:
                assert pool is not None and members is not None
                order = coarse_order(q, img, seg, pool)
                top, n_sc = coarse_topk(q, img, members, pool, probe, k)
            aps.append(ap_of_order(order, tr))
            rks.append(tr[top].sum() / min(k, tr.sum()))
            exact.append(ap_of_order(idx_judged[order[judged[order]]], tr[judged]))
            scored.append(n_sc)
        n_seg = "-" if seg is None else str(int(seg.max()) + 1)
        print(
            f"{label:32} {n_seg:>5} {np.nanmean(aps):7.3f} {np.mean(rks):7.3f} {np.nanmean(exact):10.3f} "
            f"{np.mean(scored):7.1f}",
            flush=True,
        )


# ------------------------------------------------------------------------------------ B. cost
def synthetic(n: int, dim: int, mean_len: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    lens = rng.integers(1, 2 * mean_len, size=2 * n // mean_len + 2)  # mean length mean_len: enough
    seg = np.repeat(np.arange(len(lens)), lens)[:n]
    centers = rng.normal(size=(int(seg[-1]) + 1, dim)).astype(np.float32)
    centers /= np.linalg.norm(centers, axis=1, keepdims=True)
    emb = np.empty((n, dim), np.float32)
    for s in range(0, n, 100_000):  # in chunks: bounded temporary memory
        part = centers[seg[s : s + 100_000]] + rng.normal(
            0, 0.6 / np.sqrt(dim), (len(seg[s : s + 100_000]), dim)
        )
        emb[s : s + 100_000] = part / np.linalg.norm(part, axis=1, keepdims=True)
    return emb, seg


def p50_ms(times: list[float]) -> float:
    return 1000 * statistics.median(times)


def store_stream(n: int, dim: int) -> np.ndarray:
    """bench_store's memories: visits of 100-800 frames drifting around a place's look."""
    sys.path.insert(0, str(ROOT / "benchmarks"))
    from bench_store import stream_arrays

    emb = np.empty((n, dim), np.float32)
    for start, part, _ in stream_arrays(n, dim, 0, 100_000):
        emb[start : start + len(part)] = part
    return emb


def cost(
    n: int, dim: int, mean_len: int, probes: list[int], queries: int, k: int, data: str, min_sim: float
) -> None:
    import faiss

    rng = np.random.default_rng(0)
    t = time.perf_counter()
    if data == "store":
        emb = store_stream(n, dim)
        what = "bench_store's stream (visits of 100-800 drifting frames)"
    else:
        emb, _ = synthetic(n, dim, mean_len, rng)
        what = f"planted segments of 1..{2 * mean_len - 1} frames"
    made = time.perf_counter() - t
    t = time.perf_counter()
    seg = segment(emb, min_sim, 4 * mean_len)
    pool = pooled(emb, seg)
    members = members_of(seg)
    build_seg = time.perf_counter() - t
    print(
        f"\nB. cost: {n:,} synthetic memories, dim {dim}, {what}, made in {made:.0f} s; "
        f"{len(pool):,} segments (cos >= {min_sim}, <= {4 * mean_len} frames; mean {n / len(pool):.1f} "
        f"frames) in {build_seg:.1f} s"
    )
    qi = rng.integers(0, n, queries)
    noise = 0.5 if data == "store" else 0.8
    qs = emb[qi] + rng.normal(0, noise / np.sqrt(dim), (queries, dim)).astype(np.float32)
    qs /= np.linalg.norm(qs, axis=1, keepdims=True)
    exact, times = [], []
    for q in qs:
        t = time.perf_counter()
        s = emb @ q
        top = np.argpartition(-s, k)[:k]
        times.append(time.perf_counter() - t)
        exact.append(set(top[np.argsort(-s[top])].tolist()))
    print(f"{'method':34} {'scored/query':>13} {'p50 ms':>8} {'recall@10':>10}")
    print(f"{'frame level, exact (numpy)':34} {n:>13,} {p50_ms(times):8.2f} {1.0:10.3f}", flush=True)
    for probe in probes:
        times, rec, scored = [], [], []
        for q, ex in zip(qs, exact):
            t = time.perf_counter()
            top, n_sc = coarse_topk(q, emb, members, pool, probe, k)
            times.append(time.perf_counter() - t)
            rec.append(len(ex & set(top.tolist())) / k)
            scored.append(n_sc)
        print(
            f"{f'segments, {probe} probed (numpy)':34} {statistics.mean(scored):>13,.0f} "
            f"{p50_ms(times):8.2f} {statistics.mean(rec):10.3f}",
            flush=True,
        )
    nlist = int(4 * np.sqrt(n))
    t = time.perf_counter()
    quant = faiss.IndexFlatIP(dim)
    ivf = faiss.IndexIVFFlat(quant, dim, nlist, faiss.METRIC_INNER_PRODUCT)
    ivf.train(emb[rng.choice(n, min(n, 40 * nlist), replace=False)])
    ivf.add(emb)
    build_ivf = time.perf_counter() - t
    for nprobe in (8, 32):
        ivf.nprobe = nprobe
        times, rec = [], []
        for q, ex in zip(qs, exact):
            t = time.perf_counter()
            _, ids = ivf.search(q[None, :], k)
            times.append(time.perf_counter() - t)
            rec.append(len(ex & set(ids[0].tolist())) / k)
        scored = nlist + n * nprobe / nlist
        print(
            f"{f'FAISS IVF nlist {nlist}, nprobe {nprobe}':34} {scored:>13,.0f} "
            f"{p50_ms(times):8.2f} {statistics.mean(rec):10.3f}",
            flush=True,
        )
    print(f"build: segments {build_seg:.1f} s (one pass, no training), IVF {build_ivf:.1f} s")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--n", type=int, default=1_000_000, help="synthetic memories for the cost part (0: skip)")
    ap.add_argument("--dim", type=int, default=384)
    ap.add_argument("--mean-len", type=int, default=10, help="mean true segment length (synthetic)")
    ap.add_argument("--probe", type=int, default=5, help="segments probed in the quality part")
    ap.add_argument("--probes", default="10,32,100", help="segments probed in the cost part")
    ap.add_argument("--queries", type=int, default=200)
    ap.add_argument("--cache-dir", type=Path, default=ROOT / ".ravenmem-cache" / "eval")
    ap.add_argument("--skip-quality", action="store_true")
    ap.add_argument(
        "--data", choices=("store", "planted"), default="store", help="synthetic data (cost part)"
    )
    ap.add_argument("--min-sim", type=float, default=0.9, help="segmentation threshold (cost part)")
    a = ap.parse_args()
    if not a.skip_quality:
        quality(a.cache_dir, a.probe, 10)
        quality_all_frames(a.cache_dir, a.probe, 10)
    if a.n:
        cost(a.n, a.dim, a.mean_len, [int(p) for p in a.probes.split(",")], a.queries, 10, a.data, a.min_sim)


if __name__ == "__main__":
    main()
