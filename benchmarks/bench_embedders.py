"""The offline embedder on real TUM frames: its runtimes side by side, then its designs.

Runtimes (`--part runtimes`): the image network through onnxruntime (the default), through
torch (extra `torch`, skipped without it) and through onnxruntime with int8 weights and
activations (static QDQ quantisation calibrated on TUM frames that are not labelled; a
measurement only, see docs/embedders.md). Per runtime, in rounds that alternate the runtimes
(medians; the machine is shared): text -> frame mAP of the default design, the largest
difference of its vectors from torch's, and frames/s at ingest's batch size (16 frames, 80
tiles) of (1) the bare network on ready tiles, (2) `embed_images` (tiling + network + pooling),
(3) the whole ingest path (`ingest` of the TUM recording into a fresh memory, every frame kept, no
OCR, default thumbnails: decoding, tiling, network, store). Ratio = ingest time per frame / bare
network time per frame (target <= 1.2); target every-frame ingest >= 13 frames/s (2x the 6.5
keyframes/s measured before onnxruntime).

Designs (`--part designs`):

Ground truth: benchmarks/data/tum_labels.json (91 frames of TUM fr1_rpy labelled by eye with the
objects visible). For every design, each labelled object's query ("a computer keyboard", ...)
ranks the 91 frames; we report mean average precision (mAP) over all queries and over the
small-object queries (mug, game controller, mouse, telephone), mean precision@5, the expected AP of a
random ranking, and images/s of the whole embed_images call (tiling + one batched forward pass +
pooling) with onnxruntime limited to --threads threads. The metrics and the labels reader are
`ravenmem.eval.retrieval`, shared with `ravenmem eval study embedders` (which compares whole
embedders, text->image and image->image; this script compares the offline designs).

    PYTHONPATH=src python benchmarks/bench_embedders.py --threads 2 [--part runtimes|designs|all]
"""

from __future__ import annotations

import argparse
import importlib.util
import itertools
import os
import statistics
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))

from ravenmem.embed.offline import OfflineConfig, OfflineEmbedder, RunOptions  # noqa: E402
from ravenmem.eval.retrieval import (  # noqa: E402
    MIN_POSITIVES,
    average_precision,
    load_images,
    load_labels,
    summarize_direction,
    text_to_image,
)

DEFAULT_DATA = Path(os.environ.get("RAVENMEM_TUM", ROOT.parent / "shared" / "data" / "tum_fr1_rpy"))
LABELS = ROOT / "benchmarks" / "data" / "tum_labels.json"
INGEST_BATCH = 16  # ingest.pipeline.ingest's default batch_size
TARGET_RATIO = 1.2
TARGET_FPS = 2 * 6.5


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


class _Int8Net:
    """The onnxruntime network with int8 weights and activations (QDQ, per-channel weights),
    calibrated on `calib` tiles; replaces an embedder's network for measuring only."""

    def __init__(self, emb: OfflineEmbedder, calib: np.ndarray, threads: int) -> None:
        from onnxruntime.quantization import CalibrationDataReader, QuantFormat, QuantType, quantize_static

        from ravenmem.embed import _effnet_onnx, _onnx
        from ravenmem.embed._torchfile import load_state_dict

        emb._load()
        self.classifier_weight = emb._net.classifier_weight
        batches = iter([{"pixels": calib[i : i + 8]} for i in range(0, len(calib), 8)])

        class Reader(CalibrationDataReader):
            def get_next(self) -> dict | None:
                return next(batches, None)

        sd = load_state_dict(_effnet_onnx.weights_path())
        with tempfile.TemporaryDirectory() as d:
            src, dst = Path(d) / "fp32.onnx", Path(d) / "int8.onnx"
            src.write_bytes(_effnet_onnx.build_graph(sd).SerializeToString())
            quantize_static(
                src,
                dst,
                Reader(),
                quant_format=QuantFormat.QDQ,
                per_channel=True,
                activation_type=QuantType.QUInt8,
                weight_type=QuantType.QInt8,
            )
            self.session = _onnx.session(dst.read_bytes(), threads)

    def __call__(self, batch: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        feats, logits = self.session.run(["features", "logits"], {"pixels": batch})
        return feats, logits


def _rate(fn: Callable[[], int]) -> float:
    """Items per second of one call of `fn` (which returns how many items it did)."""
    t0 = time.perf_counter()
    n = fn()
    return n / (time.perf_counter() - t0)


def _ingest_rate(emb: OfflineEmbedder, data: Path, frames: int) -> float:
    import ravenmem
    from ravenmem.ingest.keyframes import KeyframeConfig
    from ravenmem.ingest.pipeline import ingest
    from ravenmem.ingest.sources import open_source

    class First:
        def __init__(self, src) -> None:
            self.src, self.name = src, src.name

        @property
        def stats(self):
            return self.src.stats

        def __iter__(self):
            return itertools.islice(iter(self.src), frames)

    with tempfile.TemporaryDirectory() as d:
        mem = ravenmem.create(Path(d) / "m.mem", embedder=emb, ocr=False)
        t0 = time.perf_counter()
        rep = ingest(First(open_source(str(data), "tum")), mem, KeyframeConfig.only(), progress=False)
        wall = time.perf_counter() - t0
        mem.close()
    return rep.kept / wall


def runtimes(args: argparse.Namespace, images: list[np.ndarray], queries: list[str], truth, small) -> None:
    """The runtime comparison (see the module docstring)."""
    have_torch = importlib.util.find_spec("torch") is not None
    embs: dict[str, OfflineEmbedder] = {"onnx": OfflineEmbedder(run=RunOptions(threads=args.threads))}
    if have_torch:
        embs["torch"] = OfflineEmbedder(run=RunOptions(threads=args.threads, runtime="torch"))
    calib_names = sorted((args.data / "rgb").glob("*.jpg"))[4::24]  # between the labelled every-8th frames
    from ravenmem.imageio import read_image

    if importlib.util.find_spec("onnxruntime.quantization") is not None and importlib.util.find_spec("onnx"):
        int8 = OfflineEmbedder(run=RunOptions(threads=args.threads))
        calib = int8.tiles([read_image(p) for p in calib_names])
        int8._load()
        int8._net = _Int8Net(int8, calib, args.threads)
        embs["onnx-int8"] = int8
    vecs = {}
    for name, emb in embs.items():
        vecs[name] = (
            np.concatenate(
                [emb.embed_images(images[s : s + INGEST_BATCH]) for s in range(0, len(images), INGEST_BATCH)]
            ),
            emb.embed_texts(queries),
        )
    batch_imgs = images[:INGEST_BATCH]
    tiles = embs["onnx"].tiles(batch_imgs)
    rates: dict[str, dict[str, list[float]]] = {n: {"net": [], "embed": [], "ingest": []} for n in embs}
    for _ in range(args.repeats):
        for name, emb in embs.items():
            rates[name]["net"].append(_rate(lambda e=emb: (e.forward(tiles), INGEST_BATCH)[1]))
            rates[name]["embed"].append(_rate(lambda e=emb: (e.embed_images(batch_imgs), INGEST_BATCH)[1]))
            if name != "onnx-int8":  # its vectors carry the fp32 name: never stored
                rates[name]["ingest"].append(_ingest_rate(emb, args.data, args.ingest_frames))
    print(
        f"runtimes: threads={args.threads}, batch {INGEST_BATCH} frames ({INGEST_BATCH * 5} tiles), "
        f"{args.repeats} alternating rounds, medians; ingest: first {args.ingest_frames} frames, every frame kept, no OCR"
    )
    print(
        f"{'runtime':<10} {'mAP':>6} {'small':>6} {'max|dv| img/txt vs torch':>26} {'net f/s':>8} "
        f"{'embed f/s':>9} {'ingest f/s':>10} {'ingest/net':>10}"
    )
    for name, (iv, tv) in vecs.items():
        m = evaluate(iv, tv, truth, small)
        diff = (
            f"{np.abs(iv - vecs['torch'][0]).max():.1e} / {np.abs(tv - vecs['torch'][1]).max():.1e}"
            if "torch" in vecs
            else "(no torch)"
        )
        r = {k: statistics.median(v) if v else float("nan") for k, v in rates[name].items()}
        print(
            f"{name:<10} {m['mAP']:6.3f} {m['small']:6.3f} {diff:>26} {r['net']:8.1f} {r['embed']:9.1f} "
            f"{r['ingest']:10.1f} {r['net'] / r['ingest']:10.2f}"
        )
    on = {k: statistics.median(v) for k, v in rates["onnx"].items()}
    print(
        f"onnx ingest/net = {on['net'] / on['ingest']:.2f} (target <= {TARGET_RATIO}); onnx every-frame ingest "
        f"{on['ingest']:.1f} frames/s (target >= {TARGET_FPS:.0f})"
        + (
            f"; onnx / torch: network {on['net'] / statistics.median(rates['torch']['net']):.2f}x, "
            f"ingest {on['ingest'] / statistics.median(rates['torch']['ingest']):.2f}x"
            if "torch" in rates
            else ""
        )
    )
    print(
        f"mAP of the default design, torch 0.761 before this change (docs/measured.md); load {os.getloadavg()}\n"
    )


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
    ap.add_argument("--part", choices=("runtimes", "designs", "all"), default="all")
    ap.add_argument("--ingest-frames", type=int, default=160, help="frames per ingest run (runtimes)")
    args = ap.parse_args()
    if not (args.data / "rgb").is_dir():
        sys.exit(f"error: {args.data}/rgb not found (TUM fr1_rpy); pass --data")

    names, images, objects, queries, truth, small = load(args.data)
    print(
        f"{len(names)} frames, {len(queries)} queries with >= {MIN_POSITIVES} positives: {', '.join(objects)}"
    )
    print(f"small objects: {', '.join(o for o, s in zip(objects, small) if s)}")
    if args.part in ("runtimes", "all"):
        runtimes(args, images, queries, truth, small)
    if args.part == "runtimes":
        return
    print(f"designs: onnxruntime threads={args.threads}, timing batch={args.batch}\n")

    rows = []
    outputs = {}
    for spec in args.layouts.split(","):
        tiles, res = (int(x) for x in spec.split("@"))
        emb = OfflineEmbedder(OfflineConfig(tiles=tiles, res=res), RunOptions(threads=args.threads))
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
