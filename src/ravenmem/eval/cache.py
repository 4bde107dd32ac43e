"""Memories and embeddings cached across evaluation runs.

A benchmark is run many times (methods, seeds, VLMs, thresholds) over the same recordings, and
embedding frames is the expensive part. Two caches make re-runs cheap:

- a memory per (episode content, embedder, keyframe settings, OCR, thumbnails), built once in
  `CACHE/memories/<key>/` (built in a temporary folder and renamed when complete, so a crash
  never leaves a half memory that looks finished);
- image embeddings per (embedder, image content) in `CACHE/embeddings/<embedder>.sqlite`, so that
  other keyframe settings of the same recording (the compression study) reuse the vectors.
"""

from __future__ import annotations

import hashlib
import json
import shutil
import sqlite3
import threading
import time
import uuid
from collections.abc import Iterator, Sequence
from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np

import ravenmem

from ..embed.base import Embedder
from ..fsio import atomic_write_json, publish_dir
from ..ingest.keyframes import KeyframeConfig
from ..memory import Memory
from ..types import Frame
from .types import Episode

MARKER = "eval_cache.json"
CACHE_VERSION = 1


class CachingEmbedder:
    """An embedder whose image vectors are kept on disk by image content (same name and dim)."""

    def __init__(self, inner: Embedder, cache_dir: Path) -> None:
        self.inner = inner
        cache_dir.mkdir(parents=True, exist_ok=True)
        tag = hashlib.sha1(f"{inner.name}:{inner.dim}".encode()).hexdigest()[:16]
        self.db_path = cache_dir / f"{tag}.sqlite"
        self._db = sqlite3.connect(self.db_path, check_same_thread=False, isolation_level=None)
        self._db.execute("PRAGMA journal_mode=WAL")
        self._db.execute("CREATE TABLE IF NOT EXISTS emb (key TEXT PRIMARY KEY, vec BLOB NOT NULL)")
        self._lock = threading.Lock()
        self.hits = 0
        self.misses = 0

    @property
    def name(self) -> str:
        return self.inner.name

    @property
    def dim(self) -> int:
        return self.inner.dim

    @staticmethod
    def _key(img: np.ndarray) -> str:
        h = hashlib.sha1(str(img.shape).encode())
        h.update(np.ascontiguousarray(img).tobytes())
        return h.hexdigest()

    def embed_images(self, images: Sequence[np.ndarray]) -> np.ndarray:
        keys = [self._key(im) for im in images]
        with self._lock:
            found: dict[str, np.ndarray] = {}
            for i in range(0, len(keys), 500):
                chunk = keys[i : i + 500]
                q = f"SELECT key, vec FROM emb WHERE key IN ({','.join('?' * len(chunk))})"
                for k, blob in self._db.execute(q, chunk):
                    found[k] = np.frombuffer(blob, dtype=np.float32)
        missing = [i for i, k in enumerate(keys) if k not in found]
        if missing:
            vecs = np.asarray(self.inner.embed_images([images[i] for i in missing]), dtype=np.float32)
            with self._lock:
                self._db.executemany(
                    "INSERT OR REPLACE INTO emb VALUES (?, ?)",
                    [(keys[i], vecs[j].tobytes()) for j, i in enumerate(missing)],
                )
            for j, i in enumerate(missing):
                found[keys[i]] = vecs[j]
        self.hits += len(keys) - len(missing)
        self.misses += len(missing)
        if not keys:
            return np.zeros((0, self.dim), dtype=np.float32)
        return np.stack([found[k] for k in keys]).astype(np.float32)

    def embed_texts(self, texts: Sequence[str]) -> np.ndarray:
        return self.inner.embed_texts(texts)

    def close(self) -> None:
        with self._lock:
            self._db.close()


class _Watch:
    """Pass frames through and note the first/last time and how many there were."""

    def __init__(self, inner: Any) -> None:
        self.inner = inner
        self.name = getattr(inner, "name", "frames")
        self.first_t: float | None = None
        self.last_t: float | None = None
        self.n = 0

    @property
    def stats(self) -> Any:
        return getattr(self.inner, "stats", None)

    def __iter__(self) -> Iterator[Frame]:
        for f in self.inner:
            if self.first_t is None:
                self.first_t = float(f.t)
            self.last_t = float(f.t)
            self.n += 1
            yield f


def memory_key(
    ep: Episode,
    embedder: str,
    keyframes: KeyframeConfig,
    ocr: bool,
    thumb_size: int,
    extra: dict[str, Any] | None = None,
) -> str:
    """A stable hash of everything that changes what the memory holds."""
    doc = {
        "v": CACHE_VERSION,
        "episode": ep.key,
        "embedder": embedder,
        "keyframes": asdict(keyframes),
        "ocr": ocr,
        "thumb_size": thumb_size,
        "extra": extra or {},
    }
    return hashlib.sha256(json.dumps(doc, sort_keys=True, default=str).encode()).hexdigest()[:24]


def build_memory(
    ep: Episode,
    cache_dir: Path,
    embedder: Embedder,
    keyframes: KeyframeConfig,
    ocr: bool = False,
    thumb_size: int = 320,
    source: Any = None,
    extra: dict[str, Any] | None = None,
    progress: bool = False,
) -> tuple[Memory, dict[str, Any]]:
    """Open the cached memory of an episode, building it first when absent.

    Returns the memory and its cache record (key, ingest report, first/last frame time). `source`
    overrides the episode's frames (studies pass a subsampled one; `extra` must then say how).
    """
    if ep.memory_path is not None:
        mem = ravenmem.open(ep.memory_path, embedder=embedder)
        t0, t1 = mem.time_span()
        return mem, {"key": None, "path": str(ep.memory_path), "first_t": t0, "last_t": t1, "frames": None}
    key = memory_key(ep, embedder.name, keyframes, ocr, thumb_size, extra)
    final = cache_dir / "memories" / key
    marker = final / MARKER
    if marker.exists():
        info = json.loads(marker.read_text(encoding="utf-8"))
        return ravenmem.open(final, embedder=embedder), info
    if final.exists():  # an unfinished build from an older layout: never trust it
        shutil.rmtree(final)
    from ..ingest.pipeline import ingest

    tmp = final.with_name(f".{key}.building-{uuid.uuid4().hex[:8]}")
    tmp.parent.mkdir(parents=True, exist_ok=True)
    for stale in tmp.parent.glob(f".{key}.building-*"):  # left by a build that was killed
        shutil.rmtree(stale, ignore_errors=True)
    watch = _Watch(source if source is not None else ep.frames())
    mem = ravenmem.create(tmp, embedder=embedder, ocr=ocr, thumb_size=thumb_size)
    try:
        report = ingest(watch, mem, keyframes=keyframes, progress=progress)  # type: ignore[arg-type]
    finally:
        mem.close()
    info = {
        "key": key,
        "episode": ep.id,
        "embedder": embedder.name,
        "keyframes": asdict(keyframes),
        "ocr": ocr,
        "thumb_size": thumb_size,
        "extra": extra or {},
        "first_t": watch.first_t,
        "last_t": watch.last_t,
        "frames": max(watch.n, report.frames_seen),
        "ingest": report.as_dict(),
        "built_at": time.time(),
    }
    atomic_write_json(tmp / MARKER, info, indent=1, default=str)
    publish_dir(tmp, final)
    return ravenmem.open(final, embedder=embedder), info
