"""Does the offline stack see people? Measured on the 31 frames of `examples/tum_desk`, 18 of which
show a person (`examples/tum_desk/people.txt`, labelled by eye).

ImageNet, the offline embedder's vocabulary, has no person class. Printed:

- the offline embedder's text tool on the frames: how it ranks "a person" (and other person
  words) over the frames: ROC AUC, precision at 5 and 10, and precision / recall of its top 18
  (as many as there are frames with a person);
- the same on the recording's other 60 hand-labelled frames (`benchmarks/data/tum_labels.json`),
  which are not the sample's: where the words the reasoner asks person questions with were chosen
  ("people": `SYNONYMS` in `ravenmem/agent/offline.py`);
- `ask "where did I see a person?" --offline` on a memory ingested from the sample: found or
  declined, and why (the reasoner's calibrated threshold), and the precision / recall of the
  frames it gives as evidence;
- OpenCV's classical people detectors (the HOG people detector, Haar cascades for faces, profiles
  and upper bodies) where the installed OpenCV has them: precision and recall of "a detection in
  the frame". OpenCV 5 dropped both from its main package; to measure them install OpenCV 4 beside
  it, e.g. `pip install --target /tmp/cv4 --no-deps opencv-python-headless==4.14.0.94` and run
  with `PYTHONPATH=/tmp/cv4`.

    python benchmarks/bench_person.py [--words "a person,people,someone"] [--memory DIR] [--tum DIR]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from PIL import Image

ROOT = Path(__file__).resolve().parents[1]
SAMPLE = ROOT / "examples" / "tum_desk"


def frames() -> tuple[list[str], list[np.ndarray], np.ndarray]:
    """The sample's timestamps, pictures and person labels (True where a person is visible)."""
    rows = [
        ln.split() for ln in (SAMPLE / "rgb.txt").read_text().splitlines() if ln and not ln.startswith("#")
    ]
    people = {
        ln.split()[0]
        for ln in (SAMPLE / "people.txt").read_text().splitlines()
        if ln and not ln.startswith("#")
    }
    ims = [np.asarray(Image.open(SAMPLE / name).convert("RGB")) for _, name in rows]
    return [t for t, _ in rows], ims, np.array([t in people for t, _ in rows])


def auc(score: np.ndarray, truth: np.ndarray) -> float:
    pos, neg = score[truth], score[~truth]
    return float(np.mean([(p > n) + 0.5 * (p == n) for p in pos for n in neg]))


def text_tool(ims: list[np.ndarray], truth: np.ndarray, words: list[str]) -> None:
    from ravenmem.embed.base import create_embedder

    emb = create_embedder("offline")
    vecs = emb.embed_images(ims)
    n = int(truth.sum())
    print(f"offline embedder {emb.name}, {len(ims)} frames, {n} with a person")
    print(f"{'text':<22} {'AUC':>5} {'P@5':>5} {'P@10':>5} {f'P=R@{n}':>7}")
    for word in words:
        s = vecs @ emb.embed_texts([word])[0]
        order = np.argsort(-s)
        print(
            f"{word:<22} {auc(s, truth):5.2f} {truth[order[:5]].mean():5.2f} {truth[order[:10]].mean():5.2f} "
            f"{truth[order[:n]].mean():7.2f}"
        )


def held_out(words: list[str], data: Path) -> None:
    """The same ranking on frames that are NOT the sample's: the other 60 hand-labelled frames of
    the recording (`benchmarks/data/tum_labels.json`, every 8th frame; the sample is every 24th),
    where the words person questions are asked with were chosen."""
    labels = json.loads((ROOT / "benchmarks" / "data" / "tum_labels.json").read_text())["frames"]
    sample = {ln.split()[0] for ln in (SAMPLE / "rgb.txt").read_text().splitlines() if ln and ln[0] != "#"}
    names = [n for n in labels if n.rsplit(".", 1)[0] not in sample and (data / "rgb" / n).exists()]
    if not names:
        print(f"\nheld-out frames: TUM fr1_rpy not found at {data} (--tum DIR): not measured")
        return
    truth = np.array(["person" in labels[n] for n in names])
    ims = [np.asarray(Image.open(data / "rgb" / n).convert("RGB")) for n in names]
    print(f"\nheld out: {len(names)} other labelled frames of fr1_rpy")
    text_tool(ims, truth, words)


def ask(memory: Path | None, stamps: list[str], truth: np.ndarray) -> None:
    """`ravenmem ask --offline` as a user runs it, on a memory of the sample: its answer, and the
    precision / recall of the frames it gives as evidence (every good hit of the place it chose:
    `--top-k` as many as there are frames) against the labels."""
    cli = [sys.executable, "-m", "ravenmem.cli.main"]
    with tempfile.TemporaryDirectory() as tmp:
        mem = memory or Path(tmp) / "desk.mem"
        if not (mem / "memory.json").exists():
            subprocess.run(
                [*cli, "ingest", str(SAMPLE), "--memory", str(mem)], check=True, capture_output=True
            )
        base = [*cli, "ask", "where did I see a person?", "--memory", str(mem), "--offline"]
        r = subprocess.run(base, capture_output=True, text=True)
        lines = [ln for ln in r.stdout.splitlines() if ln.startswith(("answer:", "note:", "reasoning:"))]
        print('\nravenmem ask "where did I see a person?" --offline:')
        print("\n".join(f"  {ln}" for ln in lines) or r.stderr.strip())
        r = subprocess.run([*base, "--json", "--top-k", str(len(stamps))], capture_output=True, text=True)
        ans = json.loads(r.stdout)
        person = {round(float(t), 3) for t, yes in zip(stamps, truth, strict=True) if yes}
        shown = [round(float(e["t"]), 3) in person for e in ans["evidence"]]
        if not ans["found"] or not shown:
            print("  declined: precision -, recall 0")
            return
        right = sum(shown)
        print(
            f"  its {len(shown)} evidence frames: {right} show a person: precision {right / len(shown):.2f}, "
            f"recall {right / len(person):.2f} (of {len(person)}); first 5 (what it prints): "
            f"{sum(shown[:5])}/{len(shown[:5])}"
        )


def opencv(ims: list[np.ndarray], truth: np.ndarray) -> None:
    import cv2

    print(f"\nOpenCV {cv2.__version__}")
    if not hasattr(cv2, "HOGDescriptor") or not hasattr(cv2, "CascadeClassifier"):
        print("  no HOGDescriptor / CascadeClassifier in this OpenCV (OpenCV 5 moved them out): not measured")
        return
    hog = cv2.HOGDescriptor()
    hog.setSVMDetector(cv2.HOGDescriptor_getDefaultPeopleDetector())
    cascades = {
        f"Haar {name}": cv2.CascadeClassifier(cv2.data.haarcascades + f"haarcascade_{name}.xml")
        for name in ("frontalface_default", "profileface", "upperbody", "fullbody")
    }

    def run_hog(bgr: np.ndarray, grey: np.ndarray) -> int:
        big = cv2.resize(bgr, (bgr.shape[1] * 2, bgr.shape[0] * 2))  # people here are small for 64x128
        return len(hog.detectMultiScale(big, winStride=(8, 8), padding=(8, 8), scale=1.05)[0])

    detectors = {"HOG people": run_hog} | {
        name: (
            lambda _b, g, c=c: len(c.detectMultiScale(g, scaleFactor=1.1, minNeighbors=4, minSize=(20, 20)))
        )
        for name, c in cascades.items()
    }
    print(f"  {'detector':<26} {'precision':>9} {'recall':>6} {'ms/frame':>8}")
    for name, det in detectors.items():
        hits, t0 = [], time.perf_counter()
        for im in ims:
            bgr = cv2.cvtColor(im, cv2.COLOR_RGB2BGR)
            grey = cv2.equalizeHist(cv2.cvtColor(im, cv2.COLOR_RGB2GRAY))
            hits.append(det(bgr, grey) > 0)
        ms = 1000 * (time.perf_counter() - t0) / len(ims)
        h = np.array(hits)
        prec = (h & truth).sum() / max(1, h.sum())
        print(
            f"  {name:<26} {prec:9.2f} {(h & truth).sum() / truth.sum():6.2f} {ms:8.0f}   ({h.sum()} frames flagged)"
        )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--words", default="person,a person,people,someone,a man,a woman")
    ap.add_argument("--memory", type=Path, default=None, help="a memory of the sample (default: ingest one)")
    ap.add_argument("--tum", type=Path, default=ROOT.parent / "shared" / "data" / "tum_fr1_rpy")
    args = ap.parse_args()
    stamps, ims, truth = frames()
    text_tool(ims, truth, [w.strip() for w in args.words.split(",") if w.strip()])
    held_out([w.strip() for w in args.words.split(",") if w.strip()], args.tum)
    ask(args.memory, stamps, truth)
    opencv(ims, truth)


if __name__ == "__main__":
    main()
