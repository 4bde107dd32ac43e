"""`milvus`: the store on Milvus (Milvus Lite file or a Milvus server) via pymilvus.

`milvus:///abs/path/memory.db` opens Milvus Lite (embedded, one process at a time);
`milvus://host:19530` (or `milvus://http://host:19530`) a server. One collection holds vectors
and metadata, a second small one (`<name>_meta`) the key/value meta, including the id counter:
ids are reserved in meta before rows are inserted, so they only ever increase and never repeat.

Milvus has no ORDER BY and no arithmetic filters, so the time tool and the position tool query
growing windows (a time span, a bounding box) and finish exactly in Python; region filters are
a bounding box in Milvus plus the exact disc test in Python.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import math
import re
import threading
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import InputError, StoreUnavailableError, one_line, require
from ..types import Filter, MemoryRecord, Pose
from ._common import (
    DIM_KEY,
    QUAT_COLUMNS,
    RECORD_COLUMNS,
    above,
    check_add,
    check_candidates,
    check_dim,
    check_filter,
    check_ids,
    check_limit,
    check_min_score,
    check_point,
    check_poses,
    check_query,
    import_key,
    norm_text,
    query_words,
    rank_text,
    record_from,
    record_values,
    skip_rows,
)
from .base import STORES, SourceFrames

log = logging.getLogger(__name__)

_MAXQ = 16384  # Milvus' cap on limit (and offset + limit) per query or search
_FIELDS = ["id", *RECORD_COLUMNS, "has_quat"]  # what a record is read back from
_STATE = "store.state"  # JSON: next id and an over-approximation of the time span and extent
_LIMITS = {"source": 1024, "image_path": 4096, "ocr_text": 16384}
_INSERT_ROWS = 5000  # rows per insert request: Milvus caps the size of one gRPC message


def _num(v: float) -> str:
    return repr(float(v))


def _expr(filt: Filter | None, extra: str = "") -> str:
    """Milvus filter for the time window and the region's bounding box (the disc test is ours)."""
    parts = [extra] if extra else []
    if filt is not None:
        if filt.after is not None and math.isfinite(filt.after):
            parts.append(f"t >= {_num(filt.after)}")
        if filt.before is not None and math.isfinite(filt.before):
            parts.append(f"t <= {_num(filt.before)}")
        if filt.region is not None:
            parts.append(_box(filt.region.x, filt.region.y, filt.region.r))
    return " and ".join(parts)


def _str(s: str) -> str:
    """A Milvus string literal: JSON's escaping (quotes, backslashes, control characters) is
    what Milvus' expression parser reads; non-ASCII stays as UTF-8."""
    return json.dumps(s, ensure_ascii=False)


def _box(x: float, y: float, s: float) -> str:
    pad = s + 1e-9 * (abs(x) + abs(y) + s) + 1e-12  # never lose a boundary point to rounding
    return f"x >= {_num(x - pad)} and x <= {_num(x + pad)} and y >= {_num(y - pad)} and y <= {_num(y + pad)}"


def _in_region(row: dict[str, Any], filt: Filter | None) -> bool:
    if filt is None or filt.region is None:
        return True
    dx, dy = row["x"] - filt.region.x, row["y"] - filt.region.y
    return bool(dx * dx + dy * dy <= filt.region.r * filt.region.r)


class MilvusStore:
    """Same behaviour as `LocalStore`, on Milvus; every call goes through one lock."""

    def __init__(
        self,
        uri: str,
        dim: int,
        collection: str = "ravenmem",
        index_type: str | None = None,
        nlist: int = 1024,
        nprobe: int = 32,
        token: str = "",
    ) -> None:
        pm: Any = require("pymilvus", "milvus")
        self._pm: Any = pm
        self.uri, self.dim, self.name, self.meta_name = uri, dim, collection, f"{collection}_meta"
        self.lite = not uri.startswith(("http://", "https://"))
        self.nprobe = nprobe
        self._lock = threading.RLock()
        self._closed = False
        try:
            self.client = pm.MilvusClient(uri=uri, token=token)
            version = str(self.client.get_server_version())
        except pm.exceptions.MilvusException as e:  # unreachable server, refused token, ...
            reason = one_line(getattr(e, "message", "") or e)[:200]
            raise StoreUnavailableError(f"milvus store {uri}: cannot connect ({reason})") from None
        old = re.match(r"v?2\.[0-3]\.", version) is not None
        self._infix = not old  # `like "%w%"` arrived in Milvus 2.4
        self.index_type = index_type or ("FLAT" if self.lite else "IVF_FLAT")
        self._index_params = {"nlist": nlist} if self.index_type == "IVF_FLAT" else {}
        if self.index_type == "HNSW":
            self._index_params = {"M": 16, "efConstruction": 200}
        if not self.client.has_collection(self.meta_name):
            self._create_meta()
        self.client.load_collection(self.meta_name)
        check_dim(uri, self.get_meta(DIM_KEY), dim)
        self._text_index = "Trie" if old else "INVERTED"
        if self.client.has_collection(self.name):
            fields = self.client.describe_collection(self.name)["fields"]
            vdim = next(int(f["params"]["dim"]) for f in fields if f["name"] == "v")
            check_dim(f"{uri} collection {collection}", str(vdim), dim)
            self._index_source()
        else:
            self._create_main(scalar_index="STL_SORT" if old else "INVERTED")
        self.client.load_collection(self.name)
        if self.get_meta(DIM_KEY) is None:
            self.set_meta(DIM_KEY, str(dim))
        self._state = self._load_state()

    # --- schema ----------------------------------------------------------------------------------
    def _create_main(self, scalar_index: str) -> None:
        dt = self._pm.DataType
        s = self.client.create_schema(auto_id=False, enable_dynamic_field=False)
        s.add_field("id", dt.INT64, is_primary=True)
        s.add_field("v", dt.FLOAT_VECTOR, dim=self.dim)
        for f in ("t", "x", "y", "z", "yaw", "qx", "qy", "qz", "qw"):
            s.add_field(f, dt.DOUBLE)
        s.add_field("has_quat", dt.BOOL)
        s.add_field("has_ocr", dt.BOOL)
        s.add_field("frame_index", dt.INT64)
        for f, n in _LIMITS.items():
            s.add_field(f, dt.VARCHAR, max_length=n)
        s.add_field("ocr_norm", dt.VARCHAR, max_length=_LIMITS["ocr_text"])
        ip = self.client.prepare_index_params()
        ip.add_index("v", index_type=self.index_type, metric_type="COSINE", params=self._index_params)
        for f in ("t", "x", "y"):
            ip.add_index(f, index_type=scalar_index)
        ip.add_index("source", index_type=self._text_index)
        self.client.create_collection(self.name, schema=s, index_params=ip, consistency_level="Session")

    def _index_source(self) -> None:
        """Migration: collections created before `source_frames` existed get the index on
        `source` now. Without it the lookup still works, by a scan, so a failure only logs."""
        try:
            if self.client.list_indexes(self.name, field_name="source"):
                return
            ip = self.client.prepare_index_params()
            ip.add_index("source", index_type=self._text_index)
            self.client.create_index(self.name, ip)
        except self._pm.exceptions.MilvusException as e:  # pragma: no cover - server-specific
            log.warning("%s: could not index the source field (%s); source lookups will scan", self.uri, e)

    def _create_meta(self) -> None:
        dt = self._pm.DataType
        s = self.client.create_schema(auto_id=False, enable_dynamic_field=False)
        s.add_field("key", dt.VARCHAR, is_primary=True, max_length=512)
        s.add_field("value", dt.VARCHAR, max_length=65535)
        s.add_field("dummy", dt.FLOAT_VECTOR, dim=2)  # Milvus wants a vector field in every collection
        ip = self.client.prepare_index_params()
        ip.add_index("dummy", index_type="FLAT", metric_type="L2")
        self.client.create_collection(self.meta_name, schema=s, index_params=ip, consistency_level="Session")

    def _load_state(self) -> dict[str, float]:
        raw = self.get_meta(_STATE)
        st: dict[str, float] = json.loads(raw) if raw else {"next_id": 1}
        # ids above the counter exist when a crash hit between an older reserve and insert: skip them
        rows = self._query(f"id >= {int(st['next_id'])}", ["id"])
        if rows:
            st["next_id"] = max(r["id"] for r in rows) + 1
        return st

    # --- low-level helpers -----------------------------------------------------------------------
    def _query(self, expr: str, fields: list[str]) -> list[dict[str, Any]]:
        """All rows matching `expr` (an iterator beyond Milvus' per-query cap)."""
        rows = self.client.query(self.name, filter=expr, output_fields=fields, limit=_MAXQ)
        if len(rows) < _MAXQ:
            return list(rows)
        it = self.client.query_iterator(self.name, filter=expr, output_fields=fields, batch_size=4096)
        out: list[dict[str, Any]] = []
        try:
            while batch := it.next():
                out.extend(batch)
        finally:
            it.close()
        return out

    def _count(self, expr: str = "") -> int:
        rows = self.client.query(self.name, filter=expr, output_fields=["count(*)"])
        return int(rows[0]["count(*)"])

    def _check_open(self) -> None:
        if self._closed:
            raise InputError(f"{self.uri}: the store is closed")

    # --- writes ----------------------------------------------------------------------------------
    def add(self, records: Sequence[MemoryRecord], embeddings: np.ndarray) -> list[int]:
        """Reserve ids (meta), then insert the batch; durable when Milvus acknowledges it."""
        emb = check_add(records, embeddings, self.dim)
        if not len(records):
            return []
        rows = [self._row(r, e) for r, e in zip(records, emb, strict=True)]
        with self._lock:
            self._check_open()
            st = dict(self._state)
            first = int(st["next_id"])
            ids = list(range(first, first + len(records)))
            st["next_id"] = first + len(records)
            for key, vals in (
                ("t", [r.t for r in records]),
                ("x", [r.pose.x for r in records]),
                ("y", [r.pose.y for r in records]),
                ("z", [r.pose.z for r in records]),
            ):
                st[f"{key}_min"] = min([*vals, st.get(f"{key}_min", math.inf)])
                st[f"{key}_max"] = max([*vals, st.get(f"{key}_max", -math.inf)])
            self.set_meta(_STATE, json.dumps(st))
            self._state = st
            for rid, row in zip(ids, rows, strict=True):
                row["id"] = rid
            self.client.insert(self.name, rows)
        return ids

    def add_many(
        self, batches: Iterable[tuple[Sequence[MemoryRecord], np.ndarray]], resume: str | None = None
    ) -> int:
        """Bulk import through `add`, 5,000 rows per insert. With `resume`, progress is kept in
        meta: before each insert the ids it will take are recorded as pending, after it the
        count of rows done; a rerun first checks whether a pending insert landed (its last id
        exists), so a crash between the insert and the count neither loses nor repeats rows.
        For millions of memories on a Milvus cluster, Milvus's own bulk import (files in object
        storage) is faster: see docs/store.md."""
        key = import_key(resume)
        prog: dict[str, Any] = json.loads(self.get_meta(key) or '{"rows": 0}') if key else {"rows": 0}
        if key and prog.get("pending"):
            first, n = prog.pop("pending")
            with self._lock:
                if self._query(f"id == {int(first) + int(n) - 1}", ["id"]):
                    prog["rows"] += int(n)
            self.set_meta(key, json.dumps(prog))
        added = 0
        for records, embeddings in skip_rows(batches, int(prog["rows"])):
            emb = check_add(records, embeddings, self.dim)
            for s in range(0, len(records), _INSERT_ROWS):
                part = records[s : s + _INSERT_ROWS]
                with self._lock:
                    if key:
                        prog["pending"] = [int(self._state["next_id"]), len(part)]
                        self.set_meta(key, json.dumps(prog))
                    self.add(part, emb[s : s + _INSERT_ROWS])
                    if key:
                        prog.pop("pending")
                        prog["rows"] += len(part)
                        self.set_meta(key, json.dumps(prog))
                added += len(part)
        return added

    def delete(self, ids: Iterable[int]) -> int:
        """Delete by primary key (unknown ids are ignored); returns how many existed. Milvus
        applies one delete request as a whole."""
        want = check_ids(ids)
        if len(want) == 0:
            return 0
        with self._lock:
            self._check_open()
            have: list[int] = []
            for s in range(0, len(want), 1000):
                chunk = want[s : s + 1000].tolist()
                # Strong: a delete just made must be seen (Session lags behind deletes on 2.3)
                rows = self.client.query(
                    self.name, filter=f"id in {chunk}", output_fields=["id"], consistency_level="Strong"
                )
                have += [int(r["id"]) for r in rows]
            if have:
                self.client.delete(self.name, ids=sorted(have))
        return len(have)

    def set_poses(self, ids: Sequence[int], poses: Sequence[Pose]) -> int:
        """New poses by upsert of the whole rows (Milvus has no partial update): each request
        of at most 1,000 rows is applied as a whole; a killed re-anchoring is finished by the
        memory's journal (`ravenmem.memory.anchor`), which sets every pose again. KeyError,
        before anything is written, when an id is not stored."""
        want, new = check_poses(ids, poses)
        if not want:
            return 0
        with self._lock:
            self._check_open()
            recs = self.get(want, with_embeddings=True)
            st = dict(self._state)
            rows = []
            for rec, p in zip(recs, new, strict=True):
                assert rec.embedding is not None
                rows.append(self._row(dataclasses.replace(rec, pose=p), rec.embedding) | {"id": rec.id})
                for key, v in (("x", p.x), ("y", p.y), ("z", p.z)):
                    st[f"{key}_min"] = min(v, st.get(f"{key}_min", math.inf))
                    st[f"{key}_max"] = max(v, st.get(f"{key}_max", -math.inf))
            self.set_meta(_STATE, json.dumps(st))
            self._state = st
            for s in range(0, len(rows), 1000):
                self.client.upsert(self.name, rows[s : s + 1000])
        return len(rows)

    def select(self, filt: Filter | None = None) -> np.ndarray:
        """Sorted ids the filter accepts (the disc test of a region is done here)."""
        filt = check_filter(filt)
        with self._lock:
            self._check_open()
            rows = self._query(_expr(filt) or "id >= 0", ["id", "x", "y"])
        return np.array(sorted(int(r["id"]) for r in rows if _in_region(r, filt)), np.int64)

    def _row(self, r: MemoryRecord, e: np.ndarray) -> dict[str, Any]:
        row: dict[str, Any] = dict(zip(RECORD_COLUMNS, record_values(r), strict=True))
        row.update(zip(QUAT_COLUMNS, r.pose.quat or (0.0, 0.0, 0.0, 0.0), strict=True))  # no NULLs
        row.update(
            v=e.tolist(),
            has_quat=r.pose.quat is not None,
            source=r.source or "",
            image_path=r.image_path or "",
            ocr_norm=norm_text(r.ocr_text or ""),
            has_ocr=bool(r.ocr_text),
        )
        for f, n in _LIMITS.items():
            if len(row[f].encode()) > n:
                raise InputError(f"record.{f}: longer than the {n} bytes the milvus store keeps")
        return row

    # --- tools -----------------------------------------------------------------------------------
    def search_vector(
        self,
        query: np.ndarray,
        k: int,
        filt: Filter | None = None,
        exact: bool = False,
        min_score: float | None = None,
        candidates: int | None = None,
    ) -> list[tuple[int, float]]:
        """Top-k (id, cosine) scoring at least `min_score` (when given): the top k, then the
        floor (Milvus reads no vectors of its own to re-rank, so a floor saves nothing here,
        and `candidates` is checked and has nothing to set)."""
        q, k, filt = check_query(query, self.dim), check_limit(k), check_filter(filt)
        check_candidates(candidates, k)
        return above(self._top_k(q, k, filt, exact), check_min_score(min_score))

    def _top_k(self, q: np.ndarray, k: int, filt: Filter | None, exact: bool) -> list[tuple[int, float]]:
        """Top-k (id, cosine); a region filter oversamples, then falls back to an exact scan."""
        if k == 0:
            return []
        expr = _expr(filt)
        params: dict[str, Any] = {"metric_type": "COSINE", "params": {}}
        if self.index_type == "IVF_FLAT":
            params["params"]["nprobe"] = self._index_params["nlist"] if exact else self.nprobe
        if self.index_type == "HNSW":
            params["params"]["ef"] = max(64, 4 * k)
        with self._lock:
            self._check_open()
            limit = min(_MAXQ, k if filt is None or filt.region is None else 4 * k)
            while True:
                res = self.client.search(
                    self.name,
                    data=[q[0].tolist()],
                    limit=limit,
                    filter=expr,
                    output_fields=["x", "y"],
                    search_params=params,
                )[0]
                hits = [(int(h["id"]), float(h["distance"])) for h in res if _in_region(h["entity"], filt)]
                if len(hits) >= k:
                    return hits[:k]
                if len(res) < limit:  # complete unless the ANN index missed rows the filter accepts
                    if len(res) >= min(limit, self._count(expr)):
                        return hits
                    break
                if limit == _MAXQ:
                    break
                limit = min(_MAXQ, limit * 4)
            rows = [r for r in self._query(expr, ["id", "v", "x", "y"]) if _in_region(r, filt)]
        if not rows:
            return []
        vecs = np.asarray([r["v"] for r in rows], np.float32)
        vecs /= np.maximum(np.linalg.norm(vecs, axis=1, keepdims=True), 1e-12)
        scores = vecs @ q[0]
        order = sorted(range(len(rows)), key=lambda i: (-scores[i], rows[i]["id"]))[:k]
        return [(int(rows[i]["id"]), float(scores[i])) for i in order]

    def search_text(self, text: str, k: int, filt: Filter | None = None) -> list[tuple[int, float]]:
        """Top-k (id, score in [0, 1]) over OCR text, scored like the local store."""
        k, filt = check_limit(k), check_filter(filt)
        words = query_words(text or "")
        if not words or k == 0:
            return []
        terms = [w for w in words if len(w) >= 3] or words
        with self._lock:
            self._check_open()
            rows = None
            if self._infix:
                like = " or ".join(f'ocr_norm like "%{w}%"' for w in terms)
                try:
                    rows = self._query(_expr(filt, f"({like})"), ["id", "x", "y", "ocr_text"])
                except self._pm.exceptions.MilvusException:
                    self._infix = False
            if rows is None:  # servers before 2.4 have no infix `like`: score every OCR'd memory
                rows = self._query(_expr(filt, "has_ocr == true"), ["id", "x", "y", "ocr_text"])
        cands = [(int(r["id"]), str(r["ocr_text"])) for r in rows if _in_region(r, filt)]
        return rank_text(text, cands, k)

    def by_time(self, t: float, k: int, filt: Filter | None = None) -> list[MemoryRecord]:
        """The k memories with timestamp >= t, oldest first: query a growing time window."""
        k, filt = check_limit(k), check_filter(filt)
        if not isinstance(t, (int, float, np.floating)) or math.isnan(t):
            raise InputError(f"t: expected a timestamp in seconds, got {t!r}")
        with self._lock:
            self._check_open()
            st = self._state
            if k == 0 or "t_min" not in st:
                return []
            lo = max(float(t), st["t_min"])
            if filt is not None and filt.after is not None:
                lo = max(lo, filt.after)
            n = max(1, int(st["next_id"]) - 1)
            width = max(1e-6, 2.0 * k * (st["t_max"] - st["t_min"]) / n)
            while True:
                done = lo + width > st["t_max"]
                window = f"t >= {_num(lo)}" + ("" if done else f" and t < {_num(lo + width)}")
                rows = [r for r in self._query(_expr(filt, window), _FIELDS) if _in_region(r, filt)]
                if len(rows) >= k or done:
                    break
                width *= 4
        rows.sort(key=lambda r: (r["t"], r["id"]))
        return [self._record(r) for r in rows[:k]]

    def nearest(
        self,
        x: float,
        y: float,
        z: float | None,
        k: int,
        radius: float | None = None,
        filt: Filter | None = None,
    ) -> list[tuple[int, float]]:
        """The k nearest (id, metres): query a growing box, exact distances in Python."""
        k, filt = check_limit(k), check_filter(filt)
        check_point(x, y, z, radius)
        with self._lock:
            self._check_open()
            st = self._state
            if k == 0 or "x_min" not in st:
                return []
            area = max((st["x_max"] - st["x_min"]) * (st["y_max"] - st["y_min"]), 1e-6)
            half = (
                radius
                if radius is not None
                else max(1e-3, 2 * math.sqrt(area * k / max(1, st["next_id"] - 1)))
            )
            while True:
                rows = [
                    r
                    for r in self._query(_expr(filt, _box(x, y, half)), ["id", "x", "y", "z"])
                    if _in_region(r, filt)
                ]
                d = [
                    math.sqrt(
                        (r["x"] - x) ** 2 + (r["y"] - y) ** 2 + (0.0 if z is None else (r["z"] - z) ** 2)
                    )
                    for r in rows
                ]
                covers = x - half <= st["x_min"] and x + half >= st["x_max"]
                covers = covers and y - half <= st["y_min"] and y + half >= st["y_max"]
                inside = [(int(r["id"]), di) for r, di in zip(rows, d, strict=True) if di <= half or covers]
                if radius is not None:
                    inside = [p for p in inside if p[1] <= radius]
                if len(inside) >= k or covers or radius is not None:
                    break
                half *= 2
        inside.sort(key=lambda p: (p[1], p[0]))
        return inside[:k]

    # --- records and meta --------------------------------------------------------------------------
    def get(self, ids: Sequence[int], with_embeddings: bool = False) -> list[MemoryRecord]:
        """Records in the order of `ids`; an unknown id raises KeyError."""
        want = [int(i) for i in ids]
        uniq = sorted(set(want))
        fields = _FIELDS + (["v"] if with_embeddings else [])
        found: dict[int, MemoryRecord] = {}
        with self._lock:
            self._check_open()
            for s in range(0, len(uniq), 1000):
                for r in self.client.query(
                    self.name, filter=f"id in {uniq[s : s + 1000]}", output_fields=fields
                ):
                    found[int(r["id"])] = self._record(r)
        missing = [i for i in want if i not in found]
        if missing:
            raise KeyError(f"unknown memory id(s): {missing[:10]}")
        return [found[i] for i in want]

    def source_frames(self, source: str) -> SourceFrames:
        """Every memory from `source`, sorted by (frame_index, id): one filtered query on the
        indexed `source` field (an iterator beyond Milvus' per-query cap)."""
        if not isinstance(source, str):
            raise InputError(f"source: expected a string, got {type(source).__name__}")
        with self._lock:
            self._check_open()
            rows = self._query(f"source == {_str(source)}", ["id", "frame_index", "t"])
        return SourceFrames.from_rows([(int(r["id"]), int(r["frame_index"]), float(r["t"])) for r in rows])

    @staticmethod
    def _record(r: dict[str, Any]) -> MemoryRecord:
        values = [None if c in QUAT_COLUMNS and not r["has_quat"] else r[c] for c in RECORD_COLUMNS]
        return record_from(r["id"], values, np.asarray(r["v"], np.float32) if "v" in r else None)

    def count(self, filt: Filter | None = None) -> int:
        filt = check_filter(filt)
        if filt is not None and filt.region is not None:  # the disc is tested here, not by Milvus
            return len(self.select(filt))
        with self._lock:
            self._check_open()
            return self._count(_expr(filt))

    def stats(self) -> dict[str, object]:
        """Counts, time span and extent (upper bounds after a crash), bytes on disk (Lite only)."""
        with self._lock:
            self._check_open()
            n = self._count()
            st = self._state
            size = None
            if self.lite:
                p = Path(self.uri)
                files = [p] if p.is_file() else [f for f in p.rglob("*") if f.is_file()]
                size = sum(f.stat().st_size for f in files)
            out: dict[str, object] = {"backend": "milvus", "uri": self.uri, "count": n, "dim": self.dim}
            for key in ("t", "x", "y", "z"):
                out[f"{key}_min"], out[f"{key}_max"] = st.get(f"{key}_min"), st.get(f"{key}_max")
            out.update(index=self.index_type, nprobe=self.nprobe, bytes=size)
            out["bytes_per_memory"] = size / n if size is not None and n else None
            return out

    def get_meta(self, key: str) -> str | None:
        with self._lock:
            self._check_open()
            rows = self.client.get(self.meta_name, ids=[key], output_fields=["value"])
        return str(rows[0]["value"]) if rows else None

    def set_meta(self, key: str, value: str) -> None:
        if not isinstance(key, str) or not isinstance(value, str):
            raise InputError(
                f"meta: key and value must be strings, got {type(key).__name__}, {type(value).__name__}"
            )
        with self._lock:
            self._check_open()
            self.client.upsert(self.meta_name, [{"key": key, "value": value, "dummy": [0.0, 0.0]}])

    def close(self) -> None:
        with self._lock:
            if not self._closed:
                self._closed = True
                self.client.close()

    def __enter__(self) -> MilvusStore:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


_OPTIONS = {"collection", "index_type", "nlist", "nprobe", "token"}


@STORES.register("milvus")
def open_milvus(spec: str, *, dim: int, **kwargs: Any) -> MilvusStore:
    """`milvus:/path/file.db` (Milvus Lite) or `milvus:host:19530` / `milvus:http://host:19530`."""
    unknown = sorted(set(kwargs) - _OPTIONS)
    if unknown:
        raise InputError(f"milvus store: unknown option(s) {unknown}; known: {sorted(_OPTIONS)}")
    if not spec:
        raise InputError("milvus store: give a Milvus Lite file (milvus:///path/memory.db) or host:port")
    if spec.startswith(("http://", "https://")):
        uri = spec
    elif re.fullmatch(r"[\w.\-]+:\d+", spec):
        uri = f"http://{spec}"
    else:
        path = Path(spec).expanduser().resolve()
        if path.suffix != ".db":
            raise InputError(f"milvus store: a Milvus Lite path must end in .db, got {spec!r}")
        path.parent.mkdir(parents=True, exist_ok=True)
        uri = str(path)
    return MilvusStore(uri, dim, **kwargs)
