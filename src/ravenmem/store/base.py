"""The store axis: where memories live and how the four tools query them.

A store keeps, per memory, one embedding (float32, L2-normalised, the embedder's dim), the
metadata of `MemoryRecord` and its OCR text. It assigns increasing integer ids in insertion
order. Every write call is durable when it returns (the memory is "acknowledged"): a process
killed afterwards reopens with it.

The store does not know about embedders or images; the `Memory` facade (ravenmem.memory)
turns queries into vectors and writes thumbnails. Stores are thread-safe: one thread may
`add` while others search.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np

from ..registry import Registry
from ..types import Filter, MemoryRecord, Pose


@dataclass(frozen=True)
class SourceFrames:
    """Parallel arrays over the memories of one source: ids (int64), frame indices (int64) and
    timestamps (float64, exactly as stored). `len()` is the number of memories."""

    ids: np.ndarray
    frame_index: np.ndarray
    t: np.ndarray

    def __len__(self) -> int:
        return len(self.ids)

    @classmethod
    def from_rows(cls, rows: Sequence[tuple[int, int, float]]) -> SourceFrames:
        """From (id, frame_index, t) rows in any order; sorted by (frame_index, id)."""
        ids = np.fromiter((r[0] for r in rows), np.int64, len(rows))
        idx = np.fromiter((r[1] for r in rows), np.int64, len(rows))
        t = np.fromiter((r[2] for r in rows), np.float64, len(rows))
        order = np.lexsort((ids, idx))
        return cls(ids[order], idx[order], t[order])


@dataclass(frozen=True)
class Cameras:
    """Where memories were taken from, as parallel arrays: ids (int64), times (float64) and
    `poses` (n, 7) float64: x, y, yaw and the quaternion (qx, qy, qz, qw; NaN without one).
    What the latest mode compares views with: a record's other fields are not needed to tell
    whether two memories look at the same scene."""

    ids: np.ndarray
    t: np.ndarray
    poses: np.ndarray

    def __len__(self) -> int:
        return len(self.ids)

    @classmethod
    def of(cls, records: Sequence[MemoryRecord]) -> Cameras:
        """The cameras of records in hand, in their order."""
        nan = (np.nan,) * 4
        rows = [(r.pose.x, r.pose.y, r.pose.yaw, *(r.pose.quat or nan)) for r in records]
        return cls(
            np.array([r.id for r in records], np.int64),
            np.array([r.t for r in records], np.float64),
            np.array(rows, np.float64).reshape(len(records), 7),
        )

    def take(self, keep: np.ndarray) -> Cameras:
        """The rows a boolean mask or index array selects."""
        return Cameras(self.ids[keep], self.t[keep], self.poses[keep])


@runtime_checkable
class Store(Protocol):
    dim: int

    def add(self, records: Sequence[MemoryRecord], embeddings: np.ndarray) -> list[int]:
        """Store records (their `id` is ignored) with (N, dim) embeddings; return the new ids."""
        ...

    def add_many(
        self, batches: Iterable[tuple[Sequence[MemoryRecord], np.ndarray]], resume: str | None = None
    ) -> int:
        """Bulk import: each (records, embeddings) batch is durable once the next one starts and
        searchable when this returns; returns how many memories were added. With `resume` (a
        name for this import), a rerun after a crash skips the input rows already committed."""
        ...

    def delete(self, ids: Iterable[int]) -> int:
        """Forget memories by id (unknown ids are ignored); returns how many were deleted.
        Crash-safe: a killed process leaves either all of them or none."""
        ...

    def set_poses(self, ids: Sequence[int], poses: Sequence[Pose]) -> int:
        """Give memories new poses (a re-anchoring into another map, see `ravenmem align`);
        their embeddings, times, texts and ids stay. All of them or none: one transaction where
        the backend has them. Unknown ids raise KeyError; returns how many were changed."""
        ...

    def select(self, filt: Filter | None = None) -> np.ndarray:
        """Sorted int64 ids of the memories a filter accepts (all ids without one), e.g. to
        forget everything before a time or inside a region. Callers do not change it (the
        embedded store hands out a read-only view)."""
        ...

    def search_vector(
        self,
        query: np.ndarray,
        k: int,
        filt: Filter | None = None,
        exact: bool = False,
        min_score: float | None = None,
        candidates: int | None = None,
    ) -> list[tuple[int, float]]:
        """Top-k (id, cosine) for one (dim,) query, best first, honouring the filter; `exact`
        scores every memory the filter accepts (slow unless the filter keeps few). `min_score`
        keeps only the hits that score at least that (so fewer than k when fewer do); a store
        may use it to read fewer candidates. `candidates`: how many of its index's best a
        store that re-ranks scores exactly (None: its own setting; k: the k it would return,
        in exact order among themselves, for a caller that wants good matches more than the
        exact best k); a store that does not re-rank ignores it."""
        ...

    def search_text(self, text: str, k: int, filt: Filter | None = None) -> list[tuple[int, float]]:
        """Top-k (id, score in [0, 1]) over the stored OCR text, best first; [] when none match."""
        ...

    def by_time(self, t: float, k: int, filt: Filter | None = None) -> list[MemoryRecord]:
        """The k memories with timestamp >= t, in forward chronological order."""
        ...

    def nearest(
        self,
        x: float,
        y: float,
        z: float | None,
        k: int,
        radius: float | None = None,
        filt: Filter | None = None,
    ) -> list[tuple[int, float]]:
        """The k spatially nearest (id, distance in metres), nearest first; planar when z is None."""
        ...

    def get(self, ids: Sequence[int], with_embeddings: bool = False) -> list[MemoryRecord]:
        """Records for ids, in the order given (unknown ids raise KeyError)."""
        ...

    def source_frames(self, source: str) -> SourceFrames:
        """Every memory stored from `source` (exact match on `MemoryRecord.source`), sorted by
        (frame_index, id). Ingest uses it to skip frames already stored, so that re-running an
        ingest resumes instead of duplicating; it must stay fast on a store of millions of
        memories (an index on source), and cost nothing for a source the store has never seen."""
        ...

    def count(self, filt: Filter | None = None) -> int:
        """How many memories are stored (that the filter accepts): `len(select(filt))`
        without listing them."""
        ...

    def stats(self) -> dict[str, object]:
        """Counts, time span, spatial extent, bytes on disk: what `ravenmem info` prints."""
        ...

    def get_meta(self, key: str) -> str | None: ...

    def set_meta(self, key: str, value: str) -> None: ...

    def close(self) -> None: ...


@runtime_checkable
class TextStore(Protocol):
    """A store that can change the OCR text of stored memories (the embedded store can; a
    Milvus collection cannot without re-inserting rows). A memory on such a store may read a
    frame's text after storing it (`ravenmem.memory.text`); on any other it reads it first."""

    def set_ocr_text(self, ids: Sequence[int], texts: Sequence[str]) -> int:
        """Replace the OCR text of memories `ids` in one durable transaction (the text search
        sees it at once); returns how many of them are stored (unknown ids are ignored)."""
        ...


@runtime_checkable
class CameraStore(Protocol):
    """A store that answers `by_time` with cameras only, from RAM (the embedded store keeps
    poses in its in-RAM columns). The latest mode walks hundreds of later memories per place
    to see whether the robot looked at it again, and holds hundreds of sightings per question;
    on any other store it reads their records. Each method is optional on its own."""

    def cameras(self, t: float, k: int, filt: Filter | None = None) -> Cameras:
        """`by_time`'s memories (the k from time t on that the filter accepts, in (time, id)
        order) as cameras."""
        ...

    def time_order(self, ids: Sequence[int]) -> np.ndarray | None:
        """Each id's place in (time, id) order among the stored memories (0: the first; -1:
        not stored), or None when the store cannot tell it from RAM at once (its ids do not
        follow time). Two memories are next to each other in time when their places are."""
        ...

    def cameras_of(self, ids: Sequence[int]) -> Cameras:
        """The cameras of the stored ones of `ids`, in the order given (others left out): what
        the latest mode knows of a sighting until an answer shows its record."""
        ...


STORES: Registry[Store] = Registry(
    "store", "ravenmem.stores", {"local": "ravenmem.store.local", "milvus": "ravenmem.store.milvus"}
)


def open_store(uri: str, dim: int, **kwargs: object) -> Store:
    """Open (creating if needed) a store from a URI.

    - a plain folder path (or `local:PATH`): the embedded FAISS + SQLite store in that folder;
    - `milvus:///path/file.db`: Milvus Lite; `milvus://host:19530`: a Milvus server.
    """
    if uri.startswith("milvus://"):
        return STORES.create("milvus:" + uri[len("milvus://") :], dim=dim, **kwargs)
    if uri.startswith("local:"):
        uri = uri[len("local:") :]
    return STORES.create("local:" + uri, dim=dim, **kwargs)
