"""Data and backend helpers for the store tests (a uniquely named module, imported by tests)."""

from __future__ import annotations

import socket
import uuid
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from ravenmem.store import Store, open_store
from ravenmem.types import MemoryRecord, Pose

BACKENDS = ["local", "milvus", pytest.param("milvus-server", marks=pytest.mark.server)]

OCR_TEXTS = ["EXIT", "Fire Exit ->", "Room 101", "CAUTION wet floor", "exit only", "Café Olé"]


def robot_stream(n: int, dim: int, seed: int = 0, step: float = 0.15, jump_every: int = 0) -> np.ndarray:
    """Unit vectors doing a random walk: consecutive frames are near duplicates, like a robot's."""
    rng = np.random.default_rng(seed)
    out = np.empty((n, dim), np.float32)
    v = rng.normal(size=dim)
    for i in range(n):
        if jump_every and i % jump_every == 0:
            v = rng.normal(size=dim)  # a new place
        v = v / np.linalg.norm(v) + step * rng.normal(size=dim) / np.sqrt(dim)
        out[i] = v / np.linalg.norm(v)
    return out


def ivf_stream(
    folder: Path, n: int, stored: int, dim: int = 32
) -> tuple[Store, np.ndarray, list[MemoryRecord]]:
    """An IVF store (from 1,000 memories, rebuilt in the foreground) holding the first `stored`
    of `n` robot-stream memories, added 1,000 at a time; all n embeddings and records are
    returned, for the adds a test makes later."""
    store = open_store(str(folder), dim, ann_threshold=1_000, background=False)
    emb = robot_stream(n, dim, seed=7, step=0.15, jump_every=500)
    recs = make_records(n)
    for s in range(0, stored, 1_000):
        store.add(recs[s : min(s + 1_000, stored)], emb[s : min(s + 1_000, stored)])
    return store, emb, recs


def make_records(
    n: int, seed: int = 0, t0: float = 1_700_000_000.0, shuffle: bool = False
) -> list[MemoryRecord]:
    """Poses on a wobbly loop with heights, 0.5 s apart, some with OCR text and quaternions."""
    rng = np.random.default_rng(seed)
    order = rng.permutation(n) if shuffle else np.arange(n)
    recs = []
    for i in order:
        a = 2 * np.pi * i / max(n, 1)
        pose = Pose(
            float(10 * np.cos(a) + rng.normal(0, 0.3)),
            float(6 * np.sin(a) + rng.normal(0, 0.3)),
            float(rng.uniform(0, 2)),
            float(a),
            (0.0, 0.0, float(np.sin(a / 2)), float(np.cos(a / 2))) if i % 2 else None,
        )
        recs.append(
            MemoryRecord(
                id=-1,
                t=t0 + 0.5 * float(i),
                pose=pose,
                source="cam0" if i % 3 else "cam1",
                frame_index=int(i),
                image_path=None if i % 4 == 0 else f"thumbs/{i:06d}.jpg",
                ocr_text=OCR_TEXTS[(i // 7) % len(OCR_TEXTS)] if i % 7 == 0 else "",
            )
        )
    return recs


def port_open(host: str, port: int) -> bool:
    with socket.socket() as s:
        s.settimeout(0.5)
        return s.connect_ex((host, port)) == 0


StoreOpener = Callable[..., Store]


def opener(backend: str, folder: Path, request: pytest.FixtureRequest) -> StoreOpener:
    """A function opening the same store again and again (to test reopening)."""
    if backend == "local":
        return lambda dim=16, **kw: open_store(str(folder / "mem"), dim, **kw)
    if backend == "milvus":
        pytest.importorskip("pymilvus")
        return lambda dim=16, **kw: open_store(f"milvus://{folder / 'mem.db'}", dim, **kw)
    server = request.getfixturevalue("milvus_server")
    name = "t" + uuid.uuid4().hex[:12]
    return lambda dim=16, **kw: open_store(f"milvus://{server}", dim, collection=name, **kw)


def batch_data(b: int, n: int, dim: int) -> tuple[list[MemoryRecord], np.ndarray]:
    """Deterministic batch number b (the crash test's child and parent both regenerate it)."""
    recs = make_records(n, seed=b, t0=1_700_000_000.0 + 1000.0 * b)
    return recs, robot_stream(n, dim, seed=1000 + b)
