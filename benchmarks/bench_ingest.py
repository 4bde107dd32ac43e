"""Ingest throughput and memory size on the real TUM frames with the offline embedder.

    python benchmarks/bench_ingest.py [--tum ../shared/data/tum_fr1_rpy] [--frames 200] [--threads 2]
        [--ocr-threads 1,2] [--default-only]

Two settings, side by side:

- the default keyframe rules on the whole recording (723 frames, 24 s): frames seen per second
  (the recording plays at 30 frames/s: target >= 30 with OCR on, so a live robot never falls
  behind), keyframes kept, frames per keyframe and the compression against the raw decoded
  video, as `ravenmem ingest` does by default: without OCR, with OCR read in a thread while the
  next frames are embedded (the default, `text="later"`, once per `--ocr-threads` value) and with
  OCR read before each batch is stored (`text="now"`, as before);
- every frame kept (`--keyframes all`) on the first --frames frames, without and with OCR: the
  embedder's throughput in keyframes/s (targets: >= 10 without OCR, >= 1 with OCR), bytes per
  memory (target <= 8 KB without thumbnails) and the compression extrapolated to the paper's
  setting (640x480 RGB at 30 fps, keyframes at 0.12/s).
"""

from __future__ import annotations

import argparse
import itertools
import os
import tempfile
import time
from pathlib import Path

import numpy as np

from ravenmem.threads import share_cores

share_cores()  # as `ravenmem ingest` does, before FAISS loads

import ravenmem  # noqa: E402
from ravenmem.ingest.keyframes import KeyframeConfig, describe  # noqa: E402
from ravenmem.ingest.pipeline import ingest  # noqa: E402
from ravenmem.ingest.sources import open_source  # noqa: E402
from ravenmem.memory import text as text_module  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


class Limited:
    """The first n frames of a source (keeps its stats)."""

    def __init__(self, src, n: int | None) -> None:
        self.src, self.n, self.name = src, n, src.name

    @property
    def stats(self):  # sources renew their stats per iteration: always read the live one
        return self.src.stats

    def __iter__(self):
        return itertools.islice(iter(self.src), self.n)


def run(
    tum: Path,
    frames: int | None,
    ocr: bool,
    thumb: int,
    tmp: Path,
    kf: KeyframeConfig,
    name: str,
    text: str = "later",
) -> dict:
    mem = ravenmem.create(tmp / f"{name}.mem", embedder="offline", ocr=ocr, thumb_size=thumb)
    mem.embedder.embed_images([np.zeros((480, 640, 3), "uint8")])  # load weights outside the timing
    # the OCR models load inside the timing (about 0.5 s), as `ravenmem ingest` pays it
    empty_bytes = int(mem.store.stats()["bytes"])
    t = time.perf_counter()
    rep = ingest(Limited(open_source(str(tum), "tum"), frames), mem, kf, progress=False, text=text)
    wall = time.perf_counter() - t
    info = mem.info()
    marginal = (int(info["store_bytes"]) - empty_bytes) / max(rep.kept, 1)
    mem.close()
    return {"rep": rep, "wall": wall, "kf_per_s": rep.kept / wall, "info": info, "marginal_bytes": marginal}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--tum", type=Path, default=ROOT.parent / "shared" / "data" / "tum_fr1_rpy")
    ap.add_argument("--frames", type=int, default=200)
    ap.add_argument("--ocr-frames", type=int, default=40)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument(
        "--ocr-threads", default="1", help="OCR threads when text is read in a thread (list: each)"
    )
    ap.add_argument("--default-only", action="store_true", help="only the default-keyframe rows")
    a = ap.parse_args()
    os.environ["RAVENMEM_THREADS"] = str(a.threads)  # the offline embedder's onnxruntime threads
    every = KeyframeConfig.only()
    print(f"load average before: {os.getloadavg()[0]:.1f} ({os.cpu_count()} cores)")
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        default = run(a.tum, None, ocr=False, thumb=320, tmp=tmp, kf=KeyframeConfig(), name="default")
        rows = [("no OCR", default)]
        for n in [int(v) for v in a.ocr_threads.split(",")]:
            text_module.TEXT_THREADS = n
            r = run(a.tum, None, ocr=True, thumb=320, tmp=tmp, kf=KeyframeConfig(), name=f"later{n}")
            rows.append((f"OCR in a thread ({n} OCR thread{'s' if n > 1 else ''})", r))
        now = run(a.tum, None, ocr=True, thumb=320, tmp=tmp, kf=KeyframeConfig(), name="now", text="now")
        rows.append(("OCR before each batch is stored", now))
        if not a.default_only:
            plain = run(a.tum, a.frames, ocr=False, thumb=0, tmp=tmp, kf=every, name="plain")
            thumbs = run(a.tum, a.frames, ocr=False, thumb=320, tmp=tmp, kf=every, name="thumbs")
            withocr = run(a.tum, a.ocr_frames, ocr=True, thumb=320, tmp=tmp, kf=every, name="ocr")
    rep = default["rep"]
    print(f"embedder threads (onnxruntime): {a.threads}; load average after: {os.getloadavg()[0]:.1f}")
    print(f"default keyframes ({describe(KeyframeConfig())}), whole recording:")
    for label, r in rows:
        fps = r["rep"].frames_seen / r["wall"]
        print(
            f"  {label:<40}: {r['rep'].frames_seen} frames in {r['wall']:.1f} s = {fps:.1f} frames/s "
            f"= {fps / 30:.2f}x the camera's 30 (target >= 1 with OCR); {r['rep'].kept} keyframes, 1 per "
            f"{r['rep'].frames_seen / r['rep'].kept:.1f} frames"
        )
    if a.default_only:
        return
    di = default["info"]
    print(
        f"  compression vs the raw decoded video: {di['compression_vs_raw']:,.0f}x store only, "
        f"{di['compression_vs_raw_with_thumbs']:,.0f}x with 320 px thumbnails ({rep.kept} memories, "
        f"{di['store_bytes']:,} B store incl. the empty store's overhead)"
    )
    bpm = plain["marginal_bytes"]  # the store's fixed overhead (empty SQLite, FTS tables) left out
    bpm_t = bpm + thumbs["info"]["thumb_bytes"] / thumbs["rep"].kept
    raw_per_s = 640 * 480 * 3 * 30  # decoded RGB bytes per second of 30 fps VGA video
    print(f"every frame kept, first {a.frames} frames (OCR run: {a.ocr_frames}):")
    print(f"  ingest, offline embedder, no OCR : {plain['kf_per_s']:.1f} keyframes/s (target >= 10)")
    print(f"  ingest, offline embedder + OCR   : {withocr['kf_per_s']:.2f} keyframes/s (target >= 1)")
    print(
        f"  bytes per memory, no thumbnail   : {bpm:,.0f} B marginal (target <= 8192); "
        f"{plain['info']['bytes_per_memory']:,.0f} B with the empty store's overhead spread over {plain['rep'].kept}"
    )
    print(f"  bytes per memory, 320px thumbnail: {bpm_t:,.0f} B")
    print(
        f"  paper setting (VGA 30 fps raw vs 0.12 keyframes/s, no thumbnail): {raw_per_s / (0.12 * bpm):,.0f}x "
        f"(paper: 22,315x); with 320px thumbnails: {raw_per_s / (0.12 * bpm_t):,.0f}x"
    )


if __name__ == "__main__":
    main()
