"""Building, caching and running the offline embedder's ONNX graphs (onnxruntime, no torch).

The graphs are built with the `onnx` package from the weights that ship in the model packages,
on first use, and cached as `.onnx` files under the user cache directory (`base.cache_dir()`:
`$RAVENMEM_CACHE_DIR`, else `$XDG_CACHE_HOME/ravenmem`, else `~/.cache/ravenmem`, in `onnx/`),
never in a memory folder. A cache file's name carries a key over the graph version and the
weights file, so a new package version or a changed graph builds a new file; a missing or
unreadable cache is rebuilt, and an unwritable cache directory only means building in memory
every time.

Threads: onnxruntime's intra-op pool is sized deliberately (`DEFAULT_THREADS`, overridable per
embedder with `threads=`), with spinning off: a robot computer is busy with SLAM and planning,
and a pool that spins on idle cores would take their time for nothing.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from ..errors import RavenmemError
from ..fsio import atomic_open
from .base import MAX_DEFAULT_THREADS, default_threads
from .base import cache_dir as user_cache_dir

__all__ = ["MAX_DEFAULT_THREADS", "default_threads"]  # re-exported: the tests read them here

OPSET = 17


class GraphBuilder:
    """A few lines over `onnx.helper`: nodes get unique output names, constants become initializers."""

    def __init__(self) -> None:
        self.nodes: list[Any] = []
        self.inits: list[Any] = []
        self._n = 0

    def _name(self, stem: str) -> str:
        self._n += 1
        return f"{stem}_{self._n}"

    def const(self, value: ArrayLike, dtype: Any = np.float32) -> str:
        from onnx import numpy_helper

        arr = np.asarray(value)
        if arr.dtype.kind == "f":
            arr = arr.astype(dtype)
        name = self._name("c")
        self.inits.append(numpy_helper.from_array(np.ascontiguousarray(arr), name))
        return name

    def node(self, op: str, inputs: Sequence[str], name: str | None = None, **attrs: Any) -> str:
        from onnx import helper

        out = name or self._name(op.lower())
        self.nodes.append(helper.make_node(op, list(inputs), [out], name=out, **attrs))
        return out

    def model(self, graph_name: str, inputs: list[Any], outputs: list[Any]) -> Any:
        from onnx import checker, helper

        graph = helper.make_graph(self.nodes, graph_name, inputs, outputs, initializer=self.inits)
        model = helper.make_model(
            graph, opset_imports=[helper.make_opsetid("", OPSET)], producer_name="ravenmem"
        )
        model.ir_version = min(model.ir_version, 8)  # readable by onnxruntime >= 1.14
        checker.check_model(model)
        return model


def cache_dir() -> Path:
    return user_cache_dir() / "onnx"


def fingerprint(path: Path) -> str:
    """A weights file's identity for cache keys: name, size and modification time (cheap; a
    reinstall only rebuilds)."""
    st = path.stat()
    return f"{path.name}:{st.st_size}:{st.st_mtime_ns}"


def cached_model(stem: str, key_parts: list[Any], build: Callable[[], Any]) -> Path | bytes:
    """The cached graph's path, building it first when absent; the serialised model itself when
    the cache cannot be written."""
    key = hashlib.sha256(json.dumps([stem, *key_parts], default=str).encode()).hexdigest()[:16]
    path = cache_dir() / f"{stem}-{key}.onnx"
    if path.is_file() and path.stat().st_size > 0:
        return path
    data: bytes = build().SerializeToString()
    try:
        with atomic_open(path) as f:
            f.write(data)
    except OSError:
        return data
    return path


def cached_session(
    stem: str, key_parts: list[Any], build: Callable[[], Any], threads: int | None = None
) -> Any:
    """A session over the cached graph; a cache file onnxruntime cannot load is rebuilt once."""
    model = cached_model(stem, key_parts, build)
    try:
        return session(model, threads)
    except RavenmemError:
        if not isinstance(model, Path):
            raise
        model.unlink(missing_ok=True)
        return session(cached_model(stem, key_parts, build), threads)


def session(model: Path | bytes, threads: int | None = None) -> Any:
    """An onnxruntime CPU session with `threads` intra-op threads (default `default_threads()`),
    one inter-op thread and no spinning."""
    import onnxruntime as ort

    opts = ort.SessionOptions()
    opts.intra_op_num_threads = threads or default_threads()
    opts.inter_op_num_threads = 1
    opts.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
    opts.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
    opts.add_session_config_entry("session.intra_op.allow_spinning", "0")
    opts.log_severity_level = 3  # errors only: no warnings about unused initializers on stderr
    src = str(model) if isinstance(model, Path) else model
    try:
        return ort.InferenceSession(src, sess_options=opts, providers=["CPUExecutionProvider"])
    except Exception as e:  # onnxruntime raises its own exception types (Fail, InvalidGraph, ...)
        raise RavenmemError(f"onnxruntime cannot load the embedder's graph: {e}") from e
