"""OCR cost and recall per 640x480 TUM frame (target: ingest with OCR >= 1 keyframe/s on 2 cores).

Runs `OcrReader` with onnxruntime limited to --threads threads over every Nth TUM fr1_rpy frame,
twice per detector size: on the frames as they are (the office has no legible text at this
resolution, so anything read there is a false read) and with a sign pasted in (a word or room
number from a fixed list, text 18-48 px high, at a seeded random place), where a read counts
when `ocr_match_score(word, text) == 1`. Prints seconds per frame (median, 90th percentile),
frames/s (1 / mean), sign recall and false reads.

    PYTHONPATH=src python benchmarks/bench_ocr.py --threads 2 [--det-sides 736,480,320]
"""

from __future__ import annotations

import argparse
import random
import statistics
import sys
import time
from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw, ImageFont

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))

from ravenmem.embed.ocr import OcrReader, ocr_match_score  # noqa: E402

DEFAULT_DATA = ROOT.parent / "shared" / "data" / "tum_fr1_rpy"
WORDS = [
    "EXIT",
    "ROOM 214",
    "Kitchen",
    "LAB 3",
    "Meeting Room",
    "STOP",
    "Office 117",
    "FIRE DOOR",
    "Toilets",
    "B-204",
]


def with_sign(frame: np.ndarray, word: str, rng: random.Random) -> np.ndarray:
    import matplotlib

    font_path = (
        Path(matplotlib.get_data_path())
        / "fonts"
        / "ttf"
        / rng.choice(["DejaVuSans.ttf", "DejaVuSans-Bold.ttf", "DejaVuSerif.ttf"])
    )
    font = ImageFont.truetype(str(font_path), rng.randint(18, 48))
    img = Image.fromarray(frame)
    draw = ImageDraw.Draw(img)
    x0, y0, x1, y1 = draw.textbbox((0, 0), word, font=font)
    w, h = x1 - x0 + 16, y1 - y0 + 12
    x, y = rng.randint(0, img.width - w), rng.randint(0, img.height - h)
    bg, fg = rng.choice(
        [((245, 245, 240), (20, 20, 20)), ((20, 110, 40), (255, 255, 255)), ((30, 40, 120), (250, 250, 250))]
    )
    draw.rectangle([x, y, x + w, y + h], fill=bg)
    draw.text((x + 8 - x0, y + 6 - y0), word, font=font, fill=fg)
    return np.asarray(img)


def run(reader: OcrReader, frames: list[np.ndarray]) -> tuple[list[float], list[str]]:
    times, texts = [], []
    for f in frames:
        t0 = time.perf_counter()
        texts.append(reader.read(f))
        times.append(time.perf_counter() - t0)
    return times, texts


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--data", type=Path, default=DEFAULT_DATA)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--every", type=int, default=24, help="use every Nth frame")
    ap.add_argument(
        "--det-sides", default="736,480", help="detector short sides to compare (736: RapidOCR's)"
    )
    args = ap.parse_args()
    files = sorted((args.data / "rgb").glob("*.jpg"))[:: args.every]
    if not files:
        sys.exit(f"error: no frames under {args.data}/rgb (TUM fr1_rpy); pass --data")
    frames = [np.asarray(Image.open(f).convert("RGB")) for f in files]
    rng = random.Random(0)
    words = [WORDS[i % len(WORDS)] for i in range(len(frames))]
    signed = [with_sign(f, w, rng) for f, w in zip(frames, words)]
    print(
        f"{len(frames)} frames {frames[0].shape[1]}x{frames[0].shape[0]}, onnxruntime threads={args.threads}\n"
    )
    print(
        f"{'detector short side':<24} {'frames':<7} {'median s':>9} {'p90 s':>7} {'frames/s':>9} {'signs read':>11} {'false reads':>12}"
    )
    names = {736: "736 (RapidOCR default)", 480: "480 (ravenmem default)"}
    for side in (int(v) for v in args.det_sides.split(",")):
        label = names.get(side, str(side))
        reader = OcrReader(det_side=None if side == 736 else side, threads=args.threads)
        reader.read(frames[0])  # load the models outside the timing
        for kind, imgs in (("plain", frames), ("signed", signed)):
            times, texts = run(reader, imgs)
            med, p90, fps = (
                statistics.median(times),
                float(np.percentile(times, 90)),
                1 / statistics.mean(times),
            )
            if kind == "plain":
                extra = f"{'':>11} {sum(bool(t) for t in texts):>5d} frames"
            else:
                hits = sum(ocr_match_score(w, t) == 1.0 for w, t in zip(words, texts))
                extra = f"{hits:>5d}/{len(texts):<5d}"
            print(f"{label:<24} {kind:<7} {med:9.3f} {p90:7.3f} {fps:9.2f} {extra}")
            if kind == "signed":
                misses = [(w, t) for w, t in zip(words, texts) if ocr_match_score(w, t) < 1.0]
                for w, t in misses[:4]:
                    print(f"    missed {w!r}: read {t!r}")


if __name__ == "__main__":
    main()
