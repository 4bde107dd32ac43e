"""What a picture sent to the model costs, per size: JPEG bytes, base64 bytes on the wire, and an
estimate of the input tokens three model families charge for it.

The agent sends a memory's stored thumbnail byte for byte, or shrinks it to `image_max_side`; it
never enlarges one. So the size a memory is built with (`thumb_size`, default 320 px) bounds
what the model can see, and each row below is what one image costs at that longest side.
Measured on real TUM fr1_rpy frames (640x480), JPEG quality 85 (the thumbnails' default).

Token formulas (estimates of what each provider documents; a server's own count may differ):
- OpenAI GPT-4o, detail "high": fit in 2048x2048, shrink so the short side is at most 768, then
  85 + 170 per 512-px tile (OpenAI vision guide, "Calculating costs"); detail "low": 85 flat.
- Gemini 2.x: 258 tokens when both sides are <= 384 px, else 258 per 768x768 tile
  (ai.google.dev "Understand and count tokens").
- Qwen2.5-VL (vLLM, transformers): one token per 28x28 patch after rounding each side to a
  multiple of 28 (14-px patches merged 2x2; Qwen2-VL model card and preprocessor_config.json).

    PYTHONPATH=src python benchmarks/bench_images.py [--frames 8] [--sizes 160,224,320,448,512,640]
"""

from __future__ import annotations

import argparse
import base64
import io
import math
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))

import numpy as np  # noqa: E402
from PIL import Image  # noqa: E402

from ravenmem.agent.images import jpeg_of_array  # noqa: E402
from ravenmem.imageio import read_image  # noqa: E402

DATA = ROOT.parent / "shared" / "data" / "tum_fr1_rpy"


def openai_high(w: int, h: int) -> int:
    s = min(1.0, 2048 / max(w, h))
    w, h = w * s, h * s
    s = min(1.0, 768 / min(w, h))
    w, h = w * s, h * s
    return 85 + 170 * math.ceil(w / 512) * math.ceil(h / 512)


def gemini(w: int, h: int) -> int:
    if w <= 384 and h <= 384:
        return 258
    return 258 * math.ceil(w / 768) * math.ceil(h / 768)


def qwen25vl(w: int, h: int) -> int:
    return max(1, round(w / 28)) * max(1, round(h / 28))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=8, help="TUM frames to average over")
    ap.add_argument("--sizes", default="160,224,320,448,512,640", help="longest sides to measure (px)")
    args = ap.parse_args()
    rgb = sorted((DATA / "rgb").glob("*.*"))
    if not rgb:
        sys.exit(f"real TUM data not found at {DATA}")
    picks = [rgb[i] for i in np.linspace(0, len(rgb) - 1, args.frames).round().astype(int)]
    images = [read_image(p) for p in picks]
    sizes = [int(s) for s in args.sizes.split(",")]
    print(f"{len(images)} TUM frames of {images[0].shape[1]}x{images[0].shape[0]}, JPEG quality 85")
    head = f"{'max side':>8} {'W x H':>9} {'JPEG B':>8} {'base64 B':>9} {'GPT-4o high':>11} {'GPT-4o low':>10} {'Gemini':>7} {'Qwen2.5-VL':>10}"
    print(head)
    print("-" * len(head))
    base = None
    for side in sizes:
        jpegs = [jpeg_of_array(im, side) for im in images]
        w, h = Image.open(io.BytesIO(jpegs[0])).size
        nbytes = float(np.mean([len(j) for j in jpegs]))
        b64 = float(np.mean([len(base64.b64encode(j)) for j in jpegs]))
        base = base or nbytes
        print(
            f"{side:>8} {f'{w}x{h}':>9} {nbytes:>8.0f} {b64:>9.0f} {openai_high(w, h):>11} {85:>10} "
            f"{gemini(w, h):>7} {qwen25vl(w, h):>10}   ({nbytes / base:.1f}x the bytes of {sizes[0]} px)"
        )


if __name__ == "__main__":
    main()
