"""Retrieval quality of embedders on hand-labelled frames (the paper's pilot study).

Before an embedder stores a robot's memories it should rank the right frames first. A labels
file lists, per frame, the objects a person sees in it, and a text query per object:

    {"queries": {"mug": "a coffee mug", ...}, "small_objects": ["mug", ...],
     "frames": {"1305031229.528748.jpg": ["keyboard", "mug"], ...}}

(`benchmarks/data/tum_labels.json` labels 91 TUM fr1/rpy frames this way.) Two directions are
measured per embedder, over the objects seen in at least `min_positives` frames:

- text -> image: the object's query ranks all labelled frames; relevant = frames showing it.
- image -> image: each frame showing the object ranks all other frames; relevant = the other
  frames showing it (what "more views like this one" returns); APs averaged per object first.

Average precision (AP) is the mean, over the relevant frames, of the precision at each one's
rank; mAP averages AP over objects (and over the small objects alone); P@k is the fraction of
relevant frames among the first k. `chance` is what a random ranking scores in expectation.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import InputError
from ..fsio import read_text

MIN_POSITIVES = 3


@dataclass
class Labels:
    """Labelled frames: query text per object, the small objects, and the objects in each frame."""

    queries: dict[str, str]
    small: set[str]
    frames: dict[str, set[str]]

    def objects(self, min_positives: int = MIN_POSITIVES) -> list[str]:
        """Objects with a query seen in at least `min_positives` frames (fewer make AP noise)."""
        return [o for o in self.queries if sum(o in v for v in self.frames.values()) >= min_positives]

    def truth(self, objects: list[str]) -> np.ndarray:
        """(objects, frames) booleans: frame j shows object i (frames in file order)."""
        return np.array([[o in objs for objs in self.frames.values()] for o in objects], dtype=bool)


def load_labels(path: str | Path) -> Labels:
    """Read a labels file (see the module docstring); one-line errors name what is wrong."""
    p = Path(path)
    try:
        doc = json.loads(read_text(p, what="label file"))
    except (OSError, ValueError) as e:  # ValueError: not UTF-8, not JSON
        raise InputError(f"{p}: cannot read the labels JSON ({e})") from e
    queries, frames = (
        doc.get("queries") if isinstance(doc, dict) else None,
        doc.get("frames") if isinstance(doc, dict) else None,
    )
    if not isinstance(queries, dict) or not queries or not all(isinstance(v, str) for v in queries.values()):
        raise InputError(f'{p}: "queries" must map each object to its text query')
    if not isinstance(frames, dict) or not frames or not all(isinstance(v, list) for v in frames.values()):
        raise InputError(f'{p}: "frames" must map each frame file to the list of objects seen in it')
    return Labels(
        queries=dict(queries),
        small=set(doc.get("small_objects") or []),
        frames={str(f): {str(o) for o in objs} for f, objs in frames.items()},
    )


def average_precision(scores: np.ndarray, relevant: np.ndarray) -> float:
    """AP of ranking items by descending score (ties in input order); nan without relevant items."""
    order = np.argsort(-scores, kind="stable")
    rel = relevant[order]
    if not rel.any():
        return float("nan")
    hits = np.cumsum(rel)
    return float((hits[rel] / (np.flatnonzero(rel) + 1)).mean())


def precision_at(scores: np.ndarray, relevant: np.ndarray, k: int) -> float:
    """Fraction of relevant items among the k best-scored."""
    return float(relevant[np.argsort(-scores, kind="stable")[:k]].mean())


def text_to_image(
    img_vecs: np.ndarray, txt_vecs: np.ndarray, truth: np.ndarray, k: int = 5
) -> dict[str, list[float]]:
    """Per query (row of `truth`): AP and P@k of ranking the frames by text-image similarity."""
    sims = txt_vecs @ img_vecs.T
    return {
        "ap": [average_precision(s, t) for s, t in zip(sims, truth)],
        "p_at_k": [precision_at(s, t, k) for s, t in zip(sims, truth)],
    }


def image_to_image(img_vecs: np.ndarray, truth: np.ndarray, k: int = 5) -> dict[str, list[float]]:
    """Per object: AP and P@k averaged over its frames used as queries against all other frames."""
    sims = img_vecs @ img_vecs.T
    out: dict[str, list[float]] = {"ap": [], "p_at_k": []}
    for t in truth:
        aps, pks = [], []
        for q in np.flatnonzero(t):
            others = np.arange(len(t)) != q
            aps.append(average_precision(sims[q][others], t[others]))
            pks.append(precision_at(sims[q][others], t[others], k))
        out["ap"].append(float(np.nanmean(aps)))
        out["p_at_k"].append(float(np.mean(pks)))
    return out


def summarize_direction(per: dict[str, list[float]], small: np.ndarray) -> dict[str, float]:
    """mAP over all objects, over the small ones, and mean P@k."""
    ap = np.asarray(per["ap"])
    return {
        "mAP": float(np.nanmean(ap)),
        "mAP_small": float(np.nanmean(ap[small])) if small.any() else float("nan"),
        "P@k": float(np.mean(per["p_at_k"])),
    }


def load_images(labels: Labels, images_dir: str | Path) -> list[np.ndarray]:
    from ..imageio import read_image

    root = Path(images_dir)
    missing = [f for f in labels.frames if not (root / f).is_file()]
    if missing:
        raise InputError(
            f"{root}: {len(missing)} labelled frame(s) not found, e.g. {missing[0]} (check --images)"
        )
    return [read_image(root / f) for f in labels.frames]


def _embed_images(emb: Any, images: list[np.ndarray], batch: int = 16) -> np.ndarray:
    parts = [
        np.asarray(emb.embed_images(images[i : i + batch]), dtype=np.float32)
        for i in range(0, len(images), batch)
    ]
    return np.concatenate(parts)


def embedder_study(
    labels_path: str | Path,
    images_dir: str | Path,
    embedders: list[str],
    k: int = 5,
    min_positives: int = MIN_POSITIVES,
    out: str | Path | None = None,
    instances: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """mAP, small-object mAP and P@k per embedder and direction; writes `<out>/study.json` when
    `out` is given. `instances` maps a spec to a ready embedder (tests, custom embedders)."""
    from ..embed.base import create_embedder

    if not embedders:
        raise InputError("--embedders: give at least one embedder")
    if k < 1 or min_positives < 1:
        raise InputError(f"--k and --min-positives must be >= 1 (got {k}, {min_positives})")
    labels = load_labels(labels_path)
    objects = labels.objects(min_positives)
    if not objects:
        raise InputError(f"{labels_path}: no object is seen in >= {min_positives} frames")
    truth = labels.truth(objects)
    small = np.array([o in labels.small for o in objects])
    images = load_images(labels, images_dir)
    n = truth.shape[1]
    chance = {
        "text->image": float(truth.mean(axis=1).mean()),
        "image->image": float(((truth.sum(axis=1) - 1) / (n - 1)).mean()),
    }
    points = []
    for spec in embedders:
        emb = (instances or {}).get(spec) or create_embedder(spec)
        emb.embed_images(images[:1])  # loads the model: not part of the speed
        start = time.perf_counter()
        img = _embed_images(emb, images)
        seconds = time.perf_counter() - start
        txt = np.asarray(emb.embed_texts([labels.queries[o] for o in objects]), dtype=np.float32)
        for direction, per in (
            ("text->image", text_to_image(img, txt, truth, k)),
            ("image->image", image_to_image(img, truth, k)),
        ):
            points.append(
                {"embedder": spec, "name": str(emb.name), "direction": direction}
                | summarize_direction(per, small)
                | {
                    "per_object": dict(zip(objects, per["ap"])),
                    "images_per_s": n / seconds if seconds > 0 else None,
                }
            )
    doc = {
        "study": "embedders",
        "labels": str(labels_path),
        "frames": n,
        "objects": objects,
        "small_objects": [o for o in objects if o in labels.small],
        "k": k,
        "chance": chance,
        "points": points,
    }
    if out is not None:
        from ..fsio import atomic_write_json

        Path(out).mkdir(parents=True, exist_ok=True)
        atomic_write_json(Path(out) / "study.json", doc, indent=2)
    return doc
