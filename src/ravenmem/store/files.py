"""Read memories with precomputed embeddings from files, for bulk import (`ravenmem import`).

Two files, row i of one describing row i of the other:

- the embeddings: a NumPy `.npy` array (N, dim) of float16/32/64, memory-mapped, so that 10M
  x 384 floats (15 GB) are never all in RAM;
- the metadata: Parquet (needs pyarrow: `pip install 'ravenmem[eval]'`), CSV with a header, or
  JSON Lines, one memory per row with columns `t` (seconds since the Unix epoch, UTC), `x`,
  `y` (metres), and optionally `z`, `yaw` (radians), `qx qy qz qw` (an orientation quaternion,
  all four or none; the yaw then follows from it), `source`, `frame_index`, `image_path` and
  `ocr_text`.

Rows are read and checked chunk by chunk; a bad value is an `InputError` naming file, row and
column.
"""

from __future__ import annotations

import csv
import hashlib
import json
import math
import os
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import InputError, require
from ..types import MemoryRecord, Pose
from ._common import QUAT_COLUMNS, RECORD_COLUMNS

Batch = tuple[list[MemoryRecord], np.ndarray]


def open_vectors(path: Path) -> np.ndarray:
    """The (N, dim) embeddings of a .npy file, memory-mapped."""
    if path.suffix.lower() != ".npy":
        raise InputError(f"{path}: embeddings must be a NumPy .npy file (N, dim)")
    try:
        arr = np.load(path, mmap_mode="r", allow_pickle=False)
    except (OSError, ValueError) as e:
        raise InputError(f"{path}: not a readable .npy array ({e})") from None
    if arr.ndim != 2 or arr.shape[1] < 1 or arr.dtype.kind != "f":
        raise InputError(f"{path}: expected a 2-D float array (N, dim), got {arr.dtype} {arr.shape}")
    return arr


def count_rows(path: Path) -> int:
    """Rows of a metadata file (Parquet from its footer, CSV/JSONL by counting lines)."""
    kind = _kind(path)
    if kind == "parquet":
        return int(_parquet(path).metadata.num_rows)
    with open(path, "rb") as f:
        lines = sum(1 for line in f if line.strip())
    return lines - 1 if kind == "csv" else lines


def read_batches(vectors: Path, meta: Path, chunk: int = 50_000) -> tuple[int, int, Iterator[Batch]]:
    """(rows, dim, batches of (records, float32 embeddings)) after checking the files agree."""
    if chunk < 1:
        raise InputError(f"chunk: must be >= 1, got {chunk}")
    arr = open_vectors(vectors)
    if not meta.is_file():
        raise InputError(f"{meta}: no such metadata file")
    _need(_header(meta), meta)
    n = count_rows(meta)
    if n != arr.shape[0]:
        raise InputError(f"{meta} has {n} rows but {vectors} has {arr.shape[0]} embeddings")

    def batches() -> Iterator[Batch]:
        start = 0
        for cols in _column_chunks(meta, chunk):
            m = len(cols["t"])
            recs = _records(cols, m, start, meta)
            yield recs, np.asarray(arr[start : start + m], dtype=np.float32)
            start += m

    return n, int(arr.shape[1]), batches()


def import_key(vectors: Path, meta: Path) -> str:
    """A name for one import of these two files (paths, sizes, modification times), so that
    rerunning the same import resumes it and a changed file starts afresh."""
    parts = []
    for p in (vectors, meta):
        st = p.stat()
        parts.append(f"{os.path.realpath(p)}:{st.st_size}:{st.st_mtime_ns}")
    return hashlib.sha256("|".join(parts).encode()).hexdigest()[:24]


def _parquet(path: Path) -> Any:
    """The Parquet file at `path`; a file that is not one is a one-line InputError."""
    pq: Any = require("pyarrow.parquet", "eval")
    try:
        return pq.ParquetFile(path)
    except (OSError, ValueError) as e:  # pyarrow's ArrowInvalid is a ValueError
        why = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
        raise InputError(f"{path}: not a readable Parquet file ({why})") from None


def _kind(path: Path) -> str:
    ext = path.suffix.lower()
    if ext in (".parquet", ".pq"):
        return "parquet"
    if ext == ".csv":
        return "csv"
    if ext in (".jsonl", ".ndjson"):
        return "jsonl"
    raise InputError(f"{path}: metadata must be .parquet, .csv or .jsonl")


def _header(path: Path) -> list[str]:
    """The column names of a metadata file (JSON Lines: the keys of its first row)."""
    kind = _kind(path)
    if kind == "parquet":
        return list(_parquet(path).schema_arrow.names)
    with open(path, encoding="utf-8", newline="") as f:
        if kind == "csv":
            return next(csv.reader(f), [])
        first = next((line for line in f if line.strip()), "{}")
    try:
        row = json.loads(first)
    except json.JSONDecodeError as e:
        raise InputError(f"{path}:1: not valid JSON ({e.msg})") from None
    return list(row) if isinstance(row, dict) else []


def _column_chunks(path: Path, chunk: int) -> Iterator[dict[str, list[Any]]]:
    kind = _kind(path)
    if kind == "parquet":
        pf = _parquet(path)
        names = [c for c in pf.schema_arrow.names if c in RECORD_COLUMNS]
        _need(names, path)
        for batch in pf.iter_batches(batch_size=chunk, columns=names):
            yield {c: batch.column(c).to_pylist() for c in names}
        return
    rows: list[dict[str, Any]] = []
    with open(path, encoding="utf-8", newline="") as f:
        if kind == "csv":
            reader = csv.DictReader(f)
            _need(list(reader.fieldnames or []), path)
            source: Iterator[dict[str, Any]] = iter(reader)
        else:
            source = _jsonl(f, path)
        for row in source:
            rows.append(row)
            if len(rows) == chunk:
                yield _columns_of(rows)
                rows = []
    if rows:
        yield _columns_of(rows)


def _jsonl(f: Any, path: Path) -> Iterator[dict[str, Any]]:
    for i, line in enumerate(f, 1):
        if not line.strip():
            continue
        try:
            row = json.loads(line)
        except json.JSONDecodeError as e:
            raise InputError(f"{path}:{i}: not valid JSON ({e.msg})") from None
        if not isinstance(row, dict):
            raise InputError(f"{path}:{i}: expected a JSON object per line")
        if i == 1:
            _need(list(row), path)
        yield row


def _need(names: list[str], path: Path) -> None:
    missing = [c for c in ("t", "x", "y") if c not in names]
    if missing:
        raise InputError(f"{path}: missing column(s) {', '.join(missing)} (need t, x, y)")


def _columns_of(rows: list[dict[str, Any]]) -> dict[str, list[Any]]:
    present = set().union(*(r.keys() for r in rows)) | {"t", "x", "y"}
    return {c: [r.get(c) for r in rows] for c in RECORD_COLUMNS if c in present}


def _records(cols: dict[str, list[Any]], m: int, start: int, path: Path) -> list[MemoryRecord]:
    def num(name: str, i: int, default: float | None = None) -> float:
        raw = cols[name][i] if name in cols else None
        if raw is None or raw == "":
            if default is None:
                raise InputError(f"{path}: row {start + i + 1}: column {name} is empty")
            return default
        try:
            val = float(raw)
        except (TypeError, ValueError):
            raise InputError(f"{path}: row {start + i + 1}: column {name}: not a number ({raw!r})") from None
        if not math.isfinite(val):
            raise InputError(f"{path}: row {start + i + 1}: column {name}: not finite ({raw!r})")
        return val

    def text(name: str, i: int) -> str | None:
        raw = cols[name][i] if name in cols else None
        return None if raw is None else str(raw)

    has_quat = all(q in cols for q in QUAT_COLUMNS)
    out = []
    for i in range(m):
        x, y, z = num("x", i), num("y", i), num("z", i, 0.0)
        quat = None
        if has_quat and cols["qx"][i] not in (None, ""):
            quat = (num("qx", i), num("qy", i), num("qz", i), num("qw", i))
        try:
            if quat is not None:
                pose = Pose.from_quaternion(x, y, z, *quat)
            else:
                pose = Pose(x, y, z, num("yaw", i, 0.0))
        except ValueError as e:
            raise InputError(f"{path}: row {start + i + 1}: {e}") from None
        fi = cols["frame_index"][i] if "frame_index" in cols else None
        out.append(
            MemoryRecord(
                id=-1,
                t=num("t", i),
                pose=pose,
                source=text("source", i) or "",
                frame_index=start + i if fi in (None, "") else int(num("frame_index", i)),
                image_path=text("image_path", i) or None,
                ocr_text=text("ocr_text", i) or "",
            )
        )
    return out
