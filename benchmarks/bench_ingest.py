"""Ingest throughput and memory size on the real TUM frames with the offline embedder.

    python benchmarks/bench_ingest.py [--tum ../shared/data/tum_fr1_rpy] [--frames 200] [--threads 2]

Prints keyframes/s without and with OCR, bytes per memory (with and without thumbnails) and
the compression factor against the raw decoded video, also extrapolated to the paper's setting
(640x480 RGB at 30 fps, keyframes at 0.12/s). Targets: >= 10 keyframes/s without OCR,
>= 1 keyframe/s with OCR, <= 8 KB per memory without thumbnails.
"""

from __future__ import annotations

import argparse
import itertools
import tempfile
import time
from pathlib import Path

import torch

import ravenmem
from ravenmem.ingest.keyframes import KeyframeConfig
from ravenmem.ingest.pipeline import ingest
from ravenmem.ingest.sources import open_source

ROOT = Path(__file__).resolve().parents[1]


class Limited:
    """The first n frames of a source (keeps its stats)."""

    def __init__(self, src, n: int) -> None:
        self.src, self.n, self.name = src, n, src.name

    @property
    def stats(self):  # sources renew their stats per iteration: always read the live one
        return self.src.stats

    def __iter__(self):
        return itertools.islice(iter(self.src), self.n)


def run(tum: Path, frames: int, ocr: bool, thumb: int, tmp: Path) -> dict:
    mem = ravenmem.create(tmp / f"m_{ocr}_{thumb}.mem", embedder="offline", ocr=ocr, thumb_size=thumb)
    mem.embedder.embed_images(
        [__import__("numpy").zeros((480, 640, 3), "uint8")]
    )  # load weights outside the timing
    if ocr:
        mem._read_text(__import__("numpy").zeros((480, 640, 3), "uint8"))
    empty_bytes = int(mem.store.stats()["bytes"])
    t = time.perf_counter()
    rep = ingest(Limited(open_source(str(tum), "tum"), frames), mem, KeyframeConfig(), progress=False)
    wall = time.perf_counter() - t
    info = mem.info()
    marginal = (int(info["store_bytes"]) - empty_bytes) / max(rep.kept, 1)
    mem.close()
    return {"kept": rep.kept, "kf_per_s": rep.kept / wall, "info": info, "marginal_bytes": marginal}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--tum", type=Path, default=ROOT.parent / "shared" / "data" / "tum_fr1_rpy")
    ap.add_argument("--frames", type=int, default=200)
    ap.add_argument("--ocr-frames", type=int, default=40)
    ap.add_argument("--threads", type=int, default=2)
    a = ap.parse_args()
    torch.set_num_threads(a.threads)
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        plain = run(a.tum, a.frames, ocr=False, thumb=0, tmp=tmp)
        thumbs = run(a.tum, a.frames, ocr=False, thumb=320, tmp=tmp)
        withocr = run(a.tum, a.ocr_frames, ocr=True, thumb=320, tmp=tmp)
    bpm = plain["marginal_bytes"]  # the store's fixed overhead (empty SQLite, FTS tables) left out
    bpm_t = bpm + thumbs["info"]["thumb_bytes"] / thumbs["kept"]
    raw_per_s = 640 * 480 * 3 * 30  # decoded RGB bytes per second of 30 fps VGA video
    paper_ratio = raw_per_s / (0.12 * bpm)
    print(f"frames: {a.frames} (OCR run: {a.ocr_frames}), torch threads: {a.threads}")
    print(f"ingest, offline embedder, no OCR : {plain['kf_per_s']:.1f} keyframes/s (target >= 10)")
    print(f"ingest, offline embedder + OCR   : {withocr['kf_per_s']:.2f} keyframes/s (target >= 1)")
    print(
        f"bytes per memory, no thumbnail   : {bpm:,.0f} B marginal (target <= 8192); "
        f"{plain['info']['bytes_per_memory']:,.0f} B with the empty store's overhead spread over {plain['kept']}"
    )
    print(f"bytes per memory, 320px thumbnail: {bpm_t:,.0f} B")
    print(
        f"raw decoded video / memory (this clip, every frame kept): {plain['info']['compression_vs_raw']:,.0f}x"
    )
    print(
        f"paper setting (VGA 30 fps raw vs 0.12 keyframes/s, no thumbnail): {paper_ratio:,.0f}x (paper: 22,315x)"
    )
    print(f"paper setting with 320px thumbnails: {raw_per_s / (0.12 * bpm_t):,.0f}x")


if __name__ == "__main__":
    main()
