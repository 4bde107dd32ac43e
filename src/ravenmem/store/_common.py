"""Record columns, input checks and OCR-text scoring shared by the store backends.

Both backends must answer the same test suite, so everything that defines *behaviour* (what
counts as bad input, how an OCR match is scored, which columns a record is stored as) lives
here, and the backends only differ in how they fetch candidates.
"""

from __future__ import annotations

import math
import re
import unicodedata
from collections.abc import Iterable, Iterator, Sequence
from typing import Any

import numpy as np

from ..errors import EmbedderMismatchError, InputError
from ..types import Filter, MemoryRecord, Pose, check_coord

DIM_KEY = "store.dim"
_WORD = re.compile(r"[^\W_]+")

# A record as columns, in this order: what the SQLite table, the Milvus collection and the
# import/export files (`files`) hold besides the id and the vector. The quaternion is all four
# or none (None: the pose has only a yaw).
RECORD_COLUMNS = (
    "t",
    "x",
    "y",
    "z",
    "yaw",
    "qx",
    "qy",
    "qz",
    "qw",
    "source",
    "frame_index",
    "image_path",
    "ocr_text",
)
QUAT_COLUMNS = RECORD_COLUMNS[5:9]


def record_values(r: MemoryRecord) -> tuple[object, ...]:
    """A record's values in `RECORD_COLUMNS` order."""
    return (
        float(r.t),
        *pose_values(r.pose),
        r.source,
        int(r.frame_index),
        r.image_path,
        r.ocr_text or "",
    )


def record_from(rid: int, values: Sequence[Any], embedding: np.ndarray | None = None) -> MemoryRecord:
    """The record stored as `values` (in `RECORD_COLUMNS` order; an empty image path is none)."""
    t, x, y, z, yaw, qx, qy, qz, qw, source, frame_index, image_path, ocr_text = values
    try:
        quat = None if qx is None else (float(qx), float(qy), float(qz), float(qw))
        pose = Pose(float(x), float(y), float(z), float(yaw), quat)
        t = float(t)
        if not math.isfinite(t):
            raise InputError(f"t: {t!r} is not a finite number")
    except (InputError, TypeError, ValueError) as e:
        raise InputError(
            f"stored memory {rid} is damaged ({e}); the next writer of this memory sets it aside"
        ) from None
    return MemoryRecord(
        id=int(rid),
        t=t,
        pose=pose,
        source=str(source),
        frame_index=int(frame_index),
        image_path=str(image_path) if image_path else None,
        ocr_text=str(ocr_text),
        embedding=embedding,
    )


Batch = tuple[Sequence[MemoryRecord], np.ndarray]


def import_key(resume: str | None) -> str | None:
    """The meta key that keeps a named import's progress (None: the import is not resumable)."""
    if resume is None:
        return None
    if not isinstance(resume, str) or not resume.strip():
        raise InputError(f"resume: expected a non-empty name, got {resume!r}")
    return f"import.{resume}"


def skip_rows(batches: Iterable[Batch], skip: int) -> Iterator[Batch]:
    """The batches of a bulk import without their first `skip` rows (those a previous run of a
    resumed import committed)."""
    for records, embeddings in batches:
        if skip >= len(records):
            skip -= len(records)
            continue
        if skip:
            records, embeddings, skip = records[skip:], embeddings[skip:], 0
        yield records, embeddings


def check_dim(where: str, stored: str | None, dim: int) -> None:
    """Refuse to open a store built with embeddings of another size (another embedder)."""
    if stored is not None and int(stored) != dim:
        raise EmbedderMismatchError(
            f"{where}: the store holds {stored}-dim embeddings but the embedder gives {dim}-dim ones; "
            "open it with the embedder that built it"
        )


def check_limit(k: int) -> int:
    """How many rows a store call may return: any whole number >= 0 (the store serves exports
    too; the searches' bound is `ravenmem.memory.check_k`)."""
    if not isinstance(k, (int, np.integer)) or isinstance(k, bool) or k < 0:
        raise InputError(f"k: expected a non-negative integer, got {k!r}")
    return int(k)


def check_ids(ids: object) -> np.ndarray:
    """Memory ids as a sorted unique int64 array; anything but integers is an input error."""
    vals = ids.ravel().tolist() if isinstance(ids, np.ndarray) else list(ids)  # type: ignore[call-overload]
    for v in vals:
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)):
            raise InputError(f"ids: expected integer memory ids, got {v!r}")
    return np.unique(np.asarray(vals, np.int64))


def check_poses(ids: object, poses: object) -> tuple[list[int], list[Pose]]:
    """The arguments of `set_poses`: integer ids, each once, and as many `Pose`s."""
    vals = ids.ravel().tolist() if isinstance(ids, np.ndarray) else list(ids)  # type: ignore[call-overload]
    got = list(poses)  # type: ignore[call-overload]
    for v in vals:
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)):
            raise InputError(f"ids: expected integer memory ids, got {v!r}")
    if len(set(vals)) != len(vals):
        raise InputError("ids: each memory may be given one new pose only")
    if len(got) != len(vals) or not all(isinstance(p, Pose) for p in got):
        raise InputError(f"poses: expected {len(vals)} Pose objects, one per id")
    return [int(v) for v in vals], got


POSE_COLUMNS = RECORD_COLUMNS[1:9]  # x, y, z, yaw, qx, qy, qz, qw


def pose_values(p: Pose) -> tuple[float | None, ...]:
    """A pose's values in `POSE_COLUMNS` order (the quaternion all four or None)."""
    return (p.x, p.y, p.z, p.yaw, *(p.quat or (None, None, None, None)))


def check_point(x: float, y: float, z: float | None, radius: float | None) -> None:
    """The arguments of `nearest`: finite numbers, and a radius that is not negative."""
    vals = [x, y] + ([] if z is None else [z]) + ([] if radius is None else [radius])
    if not all(isinstance(v, (int, float, np.integer, np.floating)) and math.isfinite(v) for v in vals):
        raise InputError(f"nearest: x, y, z and radius must be finite numbers, got {vals}")
    if radius is not None and radius < 0:
        raise InputError(f"radius: must be >= 0, got {radius}")
    for v in vals[: 3 if z is not None else 2]:
        check_coord(v, "nearest: x, y, z")  # 1e308 would overflow the distances


def check_add(records: Sequence[MemoryRecord], embeddings: np.ndarray, dim: int) -> np.ndarray:
    """Validate a batch for `add`; return the embeddings as L2-normalised float32 (N, dim)."""
    emb = np.asarray(embeddings, dtype=np.float32)
    if emb.ndim != 2 or emb.shape[1] != dim:
        raise InputError(f"embeddings: expected shape (N, {dim}), got {tuple(emb.shape)}")
    if emb.shape[0] != len(records):
        raise InputError(f"embeddings: {emb.shape[0]} rows for {len(records)} records")
    for i, rec in enumerate(records):
        if not isinstance(rec, MemoryRecord):
            raise InputError(f"records[{i}]: expected a MemoryRecord, got {type(rec).__name__}")
        if not math.isfinite(rec.t):
            raise InputError(f"records[{i}].t: timestamp is not finite ({rec.t!r})")
    return normalise(emb, "embeddings")


def normalise(emb: np.ndarray, field: str) -> np.ndarray:
    """L2-normalise rows so inner product is cosine; zero or non-finite rows are input errors."""
    if not np.all(np.isfinite(emb)):
        raise InputError(f"{field}: contains NaN or infinite values")
    norms = np.linalg.norm(emb, axis=1, keepdims=True)
    if np.any(norms < 1e-12):
        raise InputError(f"{field}: contains an all-zero vector (no direction to compare)")
    return np.ascontiguousarray(emb / norms, dtype=np.float32)


def check_query(query: np.ndarray, dim: int) -> np.ndarray:
    q = np.asarray(query, dtype=np.float32).reshape(-1)
    if q.shape[0] != dim:
        raise InputError(f"query: expected a ({dim},) vector, got shape {tuple(np.shape(query))}")
    return normalise(q[None, :], "query")


def check_min_score(v: object) -> float | None:
    """A search's score floor: None, or a number (a cosine; -inf keeps everything)."""
    if v is None:
        return None
    if isinstance(v, bool) or not isinstance(v, (int, float, np.integer, np.floating)) or math.isnan(v):
        raise InputError(f"min_score: expected a number or None, got {v!r}")
    return float(v)


def check_candidates(v: object, k: int) -> int | None:
    """How many of the index's candidates a search scores exactly: None (the store's own
    setting) or a whole number, never fewer than k."""
    if v is None:
        return None
    if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 1:
        raise InputError(f"candidates: expected a whole number >= 1 or None, got {v!r}")
    return max(int(v), k)


def above(hits: list[tuple[int, float]], min_score: float | None) -> list[tuple[int, float]]:
    """The (id, score) hits that score at least `min_score` (all of them when it is None)."""
    return hits if min_score is None else [h for h in hits if h[1] >= min_score]


def check_filter(filt: Filter | None) -> Filter | None:
    """None for 'no filter'; an error for a region with a negative radius."""
    if filt is None or filt.empty:
        return None
    if filt.region is not None and not filt.region.r >= 0:
        raise InputError(f"filter.region.r: radius must be >= 0, got {filt.region.r!r}")
    return filt


def norm_text(text: str) -> str:
    """Case- and accent-folded text with single spaces: what OCR matching compares.

    Accents are dropped because OCR engines often miss them ("CAFE" read off a "Café" sign).
    """
    decomposed = unicodedata.normalize("NFKD", text.casefold())
    return " ".join("".join(c for c in decomposed if not unicodedata.combining(c)).split())


def query_words(query: str) -> list[str]:
    """The letter/digit runs of a query; punctuation and underscores never have to match."""
    return _WORD.findall(norm_text(query))


def ocr_score(query: str, text: str) -> float:
    """Score in [0, 1] of how well stored OCR `text` matches `query`.

    0.9 x the fraction of query characters in words found in the text (so a partial match of a
    multi-word query ranks below a full one), plus 0.1 when the whole query appears verbatim.
    """
    words = query_words(query)
    if not words:
        return 0.0
    hay = " ".join(query_words(text))
    total = sum(len(w) for w in words)
    found = sum(len(w) for w in words if w in hay)
    if found == 0:
        return 0.0
    phrase = 0.1 if " ".join(words) in hay else 0.0
    return 0.9 * found / total + phrase


def rank_text(query: str, candidates: Sequence[tuple[int, str]], k: int) -> list[tuple[int, float]]:
    """Score candidates, drop non-matches, best first (older memory first on ties)."""
    scored = [(i, ocr_score(query, text)) for i, text in candidates]
    scored = [(i, s) for i, s in scored if s > 0.0]
    scored.sort(key=lambda p: (-p[1], p[0]))
    return scored[:k]
