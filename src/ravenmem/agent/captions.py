"""The caption baseline, as ReMEmbR builds it and the RAVEN paper ran it: a VLM captions short
segments of the recording (about 3 s each, all the segment's keyframes in one request, with a
detailed description asked for), the captions are embedded with a sentence model (MiniLM by
default, offline; `encoder="mixedbread-ai/mxbai-embed-large-v1"` as in the paper's ReMEmbR rows),
and the same agent loop answers over text only (its text tool searches the captions; time and
position tools list memories with their segment's caption; no image reaches the answering
model, and, as in ReMEmbR, no similarity score either unless `show_scores=True`).

Captions live beside the memory in `captions.sqlite`: one row per segment (its memories, the
memory that stands for it, its caption, the captioning model, the text embedding), one
transaction per batch, so an interrupted run keeps what it wrote and a re-run only captions
segments that are new or grew. The segment length (seconds, or a number of keyframes when
`segment_frames` is given) is stored with the captions; opening them with another length is an
error rather than a silent mix.
"""

from __future__ import annotations

import json
import sqlite3
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ..errors import InputError, NotFoundError
from ..memory.folder import CAPTIONS
from ..memory.protocol import MemoryLike, TimeLike
from ..types import Hit, MemoryRecord
from .client import VLMClient
from .config import VLMConfig
from .images import data_url, record_jpeg
from .loop import Agent
from .tool_calls import ToolRunner

if TYPE_CHECKING:
    from .ask import MethodOptions

SEGMENT_FRAMES = 3  # consecutive keyframes per caption (ReMEmbR captions a few seconds of video)
CAPTION_PROMPT = (
    "These are {n} consecutive views from a robot's camera over a few seconds, in time order. "
    "Describe in detail what the robot sees: each object you can make out, with its colour, size "
    "and where it is relative to other things; the kind of place and its fixed features (doors, "
    "stairs, furniture, signs); any people and what they are doing; and any text you can read. "
    "Be specific and stick to what is visible. Reply with the description only."
)
SEGMENT_S = 3.0  # seconds of recording per caption, by default (ReMEmbR's and the paper's NaVQA setting)
TextEncoder = Callable[[Sequence[str]], np.ndarray]
Row = tuple[
    int, list[int], int, float, float, float, str, str
]  # first id, members, rep, t, x, y, caption, model


class MiniLMEncoder:
    """all-MiniLM-L6-v2 from the bundled package, loaded on first use, L2-normalised rows.

    Run as the offline embedder's text side runs it (`embed._text.MiniLM`, onnxruntime): the
    same vectors as sentence-transformers (tested to 2e-6) without importing torch and
    sentence-transformers, which took seconds and which a core install (the package installed
    `--no-deps`) does not have."""

    name = "all-MiniLM-L6-v2"

    def __init__(self) -> None:
        self._model: Any = None
        self._lock = threading.Lock()

    def __call__(self, texts: Sequence[str]) -> np.ndarray:
        with self._lock:
            if self._model is None:
                from ..embed._text import MiniLM

                self._model = MiniLM()
        return np.asarray(self._model.encode(list(texts)), dtype=np.float32)


class SentenceEncoder:
    """A sentence-transformers model by hub name or local folder (e.g.
    mixedbread-ai/mxbai-embed-large-v1), loaded on first use, L2-normalised rows."""

    def __init__(self, name: str) -> None:
        if not name.strip():
            raise InputError("caption encoder: give minilm, a sentence-transformers name or a model folder")
        self.name = name.strip()
        self._model: Any = None
        self._lock = threading.Lock()

    def __call__(self, texts: Sequence[str]) -> np.ndarray:
        with self._lock:
            if self._model is None:
                from ..errors import require

                st: Any = require("sentence_transformers", "hf")
                try:
                    self._model = st.SentenceTransformer(self.name, device="cpu")
                except (OSError, ValueError) as e:
                    raise InputError(f"caption encoder {self.name!r} cannot be loaded: {e}") from e
        out = self._model.encode(list(texts), normalize_embeddings=True, convert_to_numpy=True)
        return np.asarray(out, dtype=np.float32)


def text_encoder(spec: TextEncoder | str | None) -> TextEncoder:
    """The captions' text encoder: a callable as given, `None` / "minilm" for the bundled
    MiniLM (offline), else a sentence-transformers model by name or folder."""
    if spec is None or (
        isinstance(spec, str) and spec.strip().lower() in ("", "minilm", MiniLMEncoder.name.lower())
    ):
        return MiniLMEncoder()
    if isinstance(spec, str):
        return SentenceEncoder(spec)
    return spec


def segments(mem: MemoryLike, n: int | None = None, seconds: float = SEGMENT_S) -> list[list[MemoryRecord]]:
    """The memory's keyframes in time order, cut into runs of `n` keyframes when n is given,
    else into runs that each span less than `seconds` from their first keyframe."""
    recs = mem.all_records()
    if n is not None:
        return [recs[i : i + n] for i in range(0, len(recs), n)]
    out: list[list[MemoryRecord]] = []
    for rec in recs:
        if out and rec.t - out[-1][0].t < seconds:
            out[-1].append(rec)
        else:
            out.append([rec])
    return out


def _segment_label(frames: int | None, seconds: float) -> str:
    return f"{frames} keyframes" if frames is not None else f"{seconds:g} s"


class CaptionIndex:
    """Segment captions of one memory and their text embeddings; cosine search with the tools' filters."""

    def __init__(
        self,
        mem: MemoryLike,
        encoder: TextEncoder | str | None = None,
        segment_frames: int | None = None,
        segment_s: float = SEGMENT_S,
    ) -> None:
        if segment_frames is not None and segment_frames < 1:
            raise InputError(f"segment_frames must be >= 1, got {segment_frames}")
        if not segment_s > 0:
            raise InputError(f"segment_s must be > 0 seconds, got {segment_s}")
        self.mem = mem
        self.segment_s = segment_s
        self.segment = _segment_label(segment_frames, segment_s)
        self.encoder: TextEncoder = text_encoder(encoder)
        self.encoder_name = str(getattr(self.encoder, "name", type(self.encoder).__name__))
        self.segment_frames = segment_frames
        self.path = Path(mem.path) / CAPTIONS
        self._db = sqlite3.connect(self.path, check_same_thread=False)
        self._db.execute("PRAGMA journal_mode=WAL")
        self._db.execute(
            "CREATE TABLE IF NOT EXISTS segments (id INTEGER PRIMARY KEY, members TEXT NOT NULL, "
            "rep INTEGER NOT NULL, t REAL, x REAL, y REAL, caption TEXT NOT NULL, model TEXT, "
            "embedding BLOB NOT NULL, created REAL)"
        )
        self._db.execute("CREATE TABLE IF NOT EXISTS meta (key TEXT PRIMARY KEY, value TEXT)")
        self._db.commit()
        meta = dict(self._db.execute("SELECT key, value FROM meta").fetchall())
        if meta.get("encoder") not in (None, self.encoder_name):
            raise InputError(
                f"{self.path}: captions were embedded with {meta['encoder']!r}, not {self.encoder_name!r}"
            )
        stored = meta.get("segment") or (
            f"{meta['segment_frames']} keyframes" if meta.get("segment_frames") else None
        )
        if stored not in (None, self.segment):
            raise InputError(
                f"{self.path}: captions were made for segments of {stored}, not {self.segment}; "
                "open them with that segment length (segment_frames= for keyframes, segment_s= for seconds)"
            )
        self._matrix: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
        self._by_member: dict[int, str] | None = None

    def __len__(self) -> int:
        return int(self._db.execute("SELECT COUNT(*) FROM segments").fetchone()[0])

    def todo(self) -> list[list[MemoryRecord]]:
        """Segments with no caption yet, or whose memories changed since they were captioned.

        Captions of segments that no longer exist (their memories were forgotten or merged by
        `ravenmem forget` / `consolidate`, so the segments were cut anew) are deleted here."""
        stored = {int(i): json.loads(m) for i, m in self._db.execute("SELECT id, members FROM segments")}
        current = segments(self.mem, self.segment_frames, self.segment_s)
        firsts = {seg[0].id for seg in current}
        stale = [(i,) for i in stored if i not in firsts]
        if stale:
            with self._db:
                self._db.executemany("DELETE FROM segments WHERE id = ?", stale)
            self._matrix = None
            self._by_member = None
        return [seg for seg in current if stored.get(seg[0].id) != [r.id for r in seg]]

    def caption(self, mid: int) -> str | None:
        """The caption of the segment that holds memory `mid`."""
        if self._by_member is None:
            self._by_member = {
                int(m): str(c)
                for members, c in self._db.execute("SELECT members, caption FROM segments")
                for m in json.loads(members)
            }
        return self._by_member.get(mid)

    def add(self, rows: list[Row]) -> None:
        """Embed and store segment rows in one transaction."""
        if not rows:
            return
        emb = np.asarray(self.encoder([r[6] for r in rows]), dtype=np.float32)
        with self._db:
            self._db.execute("INSERT OR REPLACE INTO meta VALUES ('encoder', ?)", (self.encoder_name,))
            self._db.execute("INSERT OR REPLACE INTO meta VALUES ('segment', ?)", (self.segment,))
            self._db.executemany(
                "INSERT OR REPLACE INTO segments VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
                [(r[0], json.dumps(r[1]), *r[2:], e.tobytes(), time.time()) for r, e in zip(rows, emb)],
            )
        self._matrix = None
        self._by_member = None

    def _load(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        if self._matrix is None:
            rows = self._db.execute("SELECT rep, t, x, y, embedding FROM segments ORDER BY id").fetchall()
            reps = np.array([r[0] for r in rows], dtype=np.int64)
            meta = np.array([(r[1], r[2], r[3]) for r in rows], dtype=np.float64).reshape(-1, 3)
            emb = (
                np.stack([np.frombuffer(r[4], dtype=np.float32) for r in rows])
                if rows
                else np.zeros((0, 1), np.float32)
            )
            self._matrix = (reps, meta, emb)
        return self._matrix

    def search(
        self,
        query: str,
        k: int = 5,
        after: TimeLike = None,
        before: TimeLike = None,
        near: tuple[float, float, float] | None = None,
    ) -> list[Hit]:
        """Segments whose caption is most similar to the query (cosine), best first, as hits on the
        memory that stands for each segment; filters apply to that memory's time and place."""
        if not query or not query.strip():
            raise InputError("empty text query")
        reps, meta, emb = self._load()
        if len(reps) == 0:
            return []
        q = np.asarray(self.encoder([query]), dtype=np.float32)[0]
        scores = emb @ q
        keep = np.ones(len(reps), dtype=bool)
        if after is not None:
            keep &= meta[:, 0] >= self.mem.parse_time(after)
        if before is not None:
            keep &= meta[:, 0] <= self.mem.parse_time(before)
        if near is not None:
            keep &= (meta[:, 1] - near[0]) ** 2 + (meta[:, 2] - near[1]) ** 2 <= near[2] ** 2
        order = [i for i in np.argsort(-scores, kind="stable") if keep[i]]
        hits: list[Hit] = []
        for i in order:
            if len(hits) >= k:
                break
            try:
                (rec,) = self.mem.get([int(reps[i])])
            except NotFoundError:  # its memory was forgotten since it was captioned: skip it
                continue
            hits.append(Hit(memory=rec, score=float(scores[i])))
        return hits

    def close(self) -> None:
        self._db.close()


def caption_memories(
    mem: MemoryLike,
    vlm: VLMConfig | VLMClient | None = None,
    encoder: TextEncoder | str | None = None,
    batch: int = 16,
    prompt: str = CAPTION_PROMPT,
    progress: Callable[[int, int], None] | None = None,
    segment_frames: int | None = None,
    image_max_side: int = 0,
    segment_s: float = SEGMENT_S,
) -> int:
    """Caption every segment that has no caption yet (one request per segment, its keyframes'
    images in time order); returns how many segments were captioned now."""
    client = (
        vlm
        if isinstance(vlm, VLMClient)
        else VLMClient(vlm if isinstance(vlm, VLMConfig) else VLMConfig.resolve())
    )
    index = CaptionIndex(mem, encoder, segment_frames, segment_s)
    try:
        todo = index.todo()
        rows: list[Row] = []
        count = 0
        for i, seg in enumerate(todo):
            jpegs = [j for j in (record_jpeg(mem, r, image_max_side) for r in seg) if j is not None]
            if jpegs:
                content: list[dict[str, Any]] = [{"type": "text", "text": prompt.format(n=len(jpegs))}]
                content += [{"type": "image_url", "image_url": {"url": data_url(j)}} for j in jpegs]
                reply = client.chat([{"role": "user", "content": content}])
                client.events.clear()  # one caption per request: no trace to keep
                text = " ".join((reply.content or "").split())[:2000] or "(no description)"
                rep = seg[len(seg) // 2]
                p = rep.pose
                rows.append(
                    (seg[0].id, [r.id for r in seg], rep.id, rep.t, p.x, p.y, text, str(client.config.model))
                )
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
    """The agent loop over segment captions only: no image is ever sent to the answering model.

    The model gets the text, time and position tools (ReMEmbR's three); the text tool searches
    the captions. A caption covers `segment_s` seconds of keyframes (or `segment_frames`
    keyframes when given); `encoder` is the captions' text encoder (a callable, "minilm" or a
    sentence-transformers name); similarity scores are hidden unless `show_scores=True`."""

    name = "caption"
    attach_images = False

    def __init__(self, memory: MemoryLike, options: MethodOptions | None = None, **keywords: Any) -> None:
        from .ask import MethodOptions

        o = options or MethodOptions.of(self.name, **keywords)
        super().__init__(memory, o if o.show_scores is not None else replace(o, show_scores=False))
        encoder, captioner, segment_frames = o.encoder, o.captioner, o.segment_frames
        segment_s = SEGMENT_S if o.segment_s is None else o.segment_s
        auto_caption = o.auto_caption is not False
        self.index = CaptionIndex(memory, encoder, segment_frames, segment_s)
        if auto_caption and self.index.todo():
            enc = self.index.encoder
            caption_memories(
                memory,
                captioner or self.client,
                encoder=enc,
                segment_frames=segment_frames,
                segment_s=segment_s,
            )
            self.index.close()
            self.index = CaptionIndex(memory, enc, segment_frames, segment_s)
        if len(self.index) == 0:
            raise InputError(
                f"{memory.path} has no captions: run `ravenmem caption --memory {memory.path}` first"
            )

    def _runner(self, image: np.ndarray | None) -> ToolRunner:
        return ToolRunner(
            self.memory,
            self.ks,
            text_search=self.index.search,
            captions=self.index.caption,
            attach_images=False,
            show_scores=self.show_scores,
            time_mode=self.time_mode,
            tools=("search_text", "search_time", "search_position"),
        )

    def _embedder_name(self) -> str | None:
        return self.index.encoder_name
