"""The offline default embedder: EfficientNet-Lite0 (ImageNet classes) bridged to MiniLM text space.

Nothing here downloads anything: both models ship inside pip packages. Designs (`design=`):

- `conse` (Norouzi et al., ConSE): an image becomes the probability-weighted mean of the MiniLM
  embeddings of its top-T ImageNet class names (384-d);
- `ridge`: a ridge map fitted on the 1000 (class-name embedding -> classifier weight) pairs turns
  a text into a virtual classifier row; its transpose maps the image's 1280-d pooled features
  into the same 384-d space, where cosine approximates that virtual class's logit;
- `mix`: the normalised weighted sum of the two (384-d, weight `w` on ridge);
- `cls`: class space (1000-d): an image is sqrt of its class probabilities (cosine between two
  images is then the Bhattacharyya coefficient), a text is a sharp softmax over its similarity
  to the class names. Selective for small objects that have an ImageNet class;
- `hybrid`: `mix` and `cls` concatenated (1384-d, 5.5 KB float32), weights `a` and 1 - a on the
  two cosines.

In the 384-d space both the label bank and texts are centred on the bank mean (phrasings such
as "a photo of a ..." share a large component that otherwise swamps cosine differences), and a
text is also projected onto its nearest class names, so that queries and images are described
by the same vocabulary. Frames are tiled (`tiles.py`); `pool=fmax` keeps, per class, the larger
of the full-frame probability and half the best tile probability, so small objects count without
letting tile-level noise dominate; one vector per frame results.
`benchmarks/bench_embedders.py` measures the designs on hand-labelled TUM frames; the default is
the `mix` design with tiles: best overall mAP there within the 8 KB-per-memory budget (docs/embedders.md: "The offline design and why").

Both networks run through onnxruntime (`runtime=onnx`, the default: `_effnet_onnx`,
`_bert_onnx`), their graphs built from the packaged weights without torch and cached under the
user cache directory; `runtime=torch` runs the same weights through torch (extra `torch`). The
two give the same vectors to ~1e-5 (tested), so the runtime is not part of `name`: a memory built
with either opens and searches with the other.

Spec: `offline[:TOKEN]...`, tokens `key=value` (design, t, temp, w, a, tiles, pool, res,
threads, runtime) or the canonical tokens of `name`
(`effnet-lite0+minilm:hybrid-t100-temp3-w0.3-a0.7:tiles5-fmax:r224`), so that
`create_embedder(e.name)` rebuilds the same embedder.
"""

from __future__ import annotations

import re
import threading
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from ..errors import InputError, require
from ..spec import parts as spec_parts
from ..spec import split_pair
from .base import EMBEDDERS, l2_normalize
from .tiles import layout, tile_batch

MODEL_TOKEN = "effnet-lite0+minilm"
DESIGNS = ("conse", "ridge", "mix", "cls", "hybrid")
POOLS = ("max", "mean", "fmax")
RIDGE_ALPHA = 1.0
TEXT_TAU = 0.05  # softmax temperature of a text over the class names (projection and `cls`)
TEXT_TOPK = 5  # class names a text is projected onto in the 384-d space
MAX_TILES_PER_PASS = 64
SEM_DIM, CLS_DIM = 384, 1000
RUNTIMES = ("onnx", "torch")


@dataclass(frozen=True)
class OfflineConfig:
    """Everything that changes the vectors (and so is written into `name`)."""

    design: str = "mix"  # 384-d: 3.2 KB per memory on disk; hybrid (1384-d) measured 13.8 KB
    t: int = 100  # top-T classes kept by ConSE
    temp: float = 3.0  # softmax temperature for ConSE
    w: float = 0.3  # weight of the ridge part in `mix` (and in the `mix` half of `hybrid`)
    a: float = 0.7  # weight of the 384-d cosine in `hybrid` (1 - a on the class-space cosine)
    tiles: int = 5
    pool: str = "fmax"
    res: int = 224

    def __post_init__(self) -> None:
        if self.design not in DESIGNS:
            raise InputError(f"offline embedder: design={self.design!r}; choose one of {', '.join(DESIGNS)}")
        if self.pool not in POOLS:
            raise InputError(f"offline embedder: pool={self.pool!r}; choose one of {', '.join(POOLS)}")
        if not 1 <= self.t <= 1000:
            raise InputError(f"offline embedder: t={self.t} must be in 1..1000")
        if not 0.01 <= self.temp <= 100:
            raise InputError(f"offline embedder: temp={self.temp} must be in [0.01, 100]")
        for key in ("w", "a"):
            if not 0.0 <= getattr(self, key) <= 1.0:
                raise InputError(f"offline embedder: {key}={getattr(self, key)} must be in [0, 1]")
        if not 32 <= self.res <= 512:
            raise InputError(f"offline embedder: res={self.res} must be in 32..512")
        layout(self.tiles)  # validates

    @property
    def dim(self) -> int:
        return {"cls": CLS_DIM, "hybrid": SEM_DIM + CLS_DIM}.get(self.design, SEM_DIM)

    @property
    def name(self) -> str:
        d = self.design
        if d in ("conse", "mix", "hybrid"):
            d += f"-t{self.t}-temp{_num(self.temp)}"
        if self.design in ("mix", "hybrid"):
            d += f"-w{_num(self.w)}"
        if self.design == "hybrid":
            d += f"-a{_num(self.a)}"
        tiles = "tiles1" if self.tiles == 1 else f"tiles{self.tiles}-{self.pool}"  # one tile: nothing to pool
        return f"offline:{MODEL_TOKEN}:{d}:{tiles}:r{self.res}"


def _num(x: float) -> str:
    return f"{x:g}"


@dataclass(frozen=True)
class RunOptions:
    """How the networks run; nothing here changes the vectors, so none of it is in `name`."""

    threads: int | None = None  # intra-op threads; None: `base.default_threads()` (torch: its default)
    runtime: str = "onnx"

    def __post_init__(self) -> None:
        if self.runtime not in RUNTIMES:
            raise InputError(
                f"offline embedder: runtime={self.runtime!r}; choose one of {', '.join(RUNTIMES)}"
            )
        if self.threads is not None and not 1 <= self.threads <= 256:
            raise InputError(f"offline embedder: threads={self.threads} must be in 1..256")


_KEYS = {
    "design": str,
    "t": int,
    "temp": float,
    "w": float,
    "a": float,
    "tiles": int,
    "pool": str,
    "res": int,
}


_RUN_KEYS = {"threads": int, "runtime": str}


def parse_spec(spec: str, **kwargs: Any) -> tuple[OfflineConfig, RunOptions]:
    """Parse `spec` (+ keyword overrides) into a config (the vectors) and run options."""
    items: list[tuple[str, str]] = []
    for tok in spec_parts(spec, ":"):
        kv = split_pair(tok, empty_value=True)
        if tok == MODEL_TOKEN:
            continue
        if kv is not None:
            items.append(kv)
        elif tok.split("-")[0] in DESIGNS:
            design, *parts = tok.split("-")
            items.append(("design", design))
            for part in parts:
                pm = re.fullmatch(r"([a-z]+)(\d+(?:\.\d+)?)", part)
                if not pm:
                    raise InputError(f"offline embedder spec {spec!r}: bad design option {part!r} in {tok!r}")
                items.append((pm.group(1), pm.group(2)))
        elif m := re.fullmatch(r"tiles(\d+)(?:-(\w+))?", tok):
            items.append(("tiles", m.group(1)))
            if m.group(2):
                items.append(("pool", m.group(2)))
        elif m := re.fullmatch(r"r(\d+)", tok):
            items.append(("res", m.group(1)))
        else:
            raise InputError(
                f"offline embedder spec {spec!r}: unknown option {tok!r} "
                f"(use key=value with keys {', '.join([*_KEYS, *_RUN_KEYS])}, or a canonical name)"
            )
    items.extend((k, str(v)) for k, v in kwargs.items())
    values: dict[str, Any] = {}
    run: dict[str, Any] = {}
    for k, v in items:
        if k in _RUN_KEYS:
            run[k] = _convert(spec, k, v, _RUN_KEYS[k])
            continue
        if k == "tiles" and v.lower() in ("none", "off", "no"):
            v = "1"
        if k not in _KEYS:
            raise InputError(
                f"offline embedder spec {spec!r}: unknown option {k!r}; known: {', '.join([*_KEYS, *_RUN_KEYS])}"
            )
        values[k] = _convert(spec, k, v, _KEYS[k])
    if values.get("tiles") == 1:
        values.pop("pool", None)  # pooling means nothing for one tile; keep one config per name
    cfg = OfflineConfig(**values)
    # quantise floats to what `name` prints, so that the name rebuilds exactly this embedder
    cfg = replace(cfg, temp=float(_num(cfg.temp)), w=float(_num(cfg.w)), a=float(_num(cfg.a)))
    return cfg, RunOptions(**run)


def _convert(spec: str, key: str, value: str, typ: type) -> Any:
    try:
        return typ(value)
    except ValueError:
        raise InputError(
            f"offline embedder spec {spec!r}: {key}={value!r} is not a valid {typ.__name__}"
        ) from None


def _softmax(z: np.ndarray) -> np.ndarray:
    z = z - z.max(axis=-1, keepdims=True)
    e = np.exp(z)
    return e / e.sum(axis=-1, keepdims=True)


def _top_weighted(p: np.ndarray, k: int, bank: np.ndarray) -> np.ndarray:
    """Rows of `p` restricted to their top-k entries, times `bank`, normalised."""
    top = np.argpartition(-p, k - 1, axis=1)[:, :k]
    wts = np.zeros_like(p)
    np.put_along_axis(wts, top, np.take_along_axis(p, top, axis=1), axis=1)
    return l2_normalize(wts @ bank)


def _pool(x: np.ndarray, how: str) -> np.ndarray:
    """(N, tiles, D) -> (N, D). `fmax`: max of the full frame (tile 0) and half the best tile."""
    if x.shape[1] == 1:
        return x[:, 0]
    if how == "max":
        return x.max(axis=1)
    if how == "mean":
        return x.mean(axis=1)
    return np.maximum(x[:, 0], 0.5 * x[:, 1:].max(axis=1))


class OfflineEmbedder:
    """See the module docstring. Models load lazily and thread-safely on first use, and only the
    side that is used: a text query loads MiniLM and the label bank, never the image network, so
    creating the embedder and reading `name`/`dim` load nothing at all."""

    def __init__(self, config: OfflineConfig | None = None, run: RunOptions | None = None) -> None:
        self.config = config or OfflineConfig()
        self.run = run or RunOptions()
        self._lock = threading.Lock()
        self._net: Any = None
        self._text: Any = None
        self._bank: np.ndarray | None = None  # (1000, 384) centred, normalised
        self._mu: np.ndarray | None = None  # (384,) bank mean
        self._ridge: np.ndarray | None = None  # (384, 1280)

    @property
    def name(self) -> str:
        return self.config.name

    @property
    def dim(self) -> int:
        return self.config.dim

    def _load_text(self) -> None:
        """MiniLM and the label bank: all a text query needs (no image model)."""
        with self._lock:
            if self._bank is not None:
                return
            from ._text import MiniLM, class_names, load_label_bank

            self._set_threads()
            text = MiniLM(self.run.runtime, self.run.threads)
            raw = load_label_bank(text, class_names())
            self._text = text
            self._mu = raw.mean(axis=0)
            self._bank = l2_normalize(raw - self._mu)

    def _load(self) -> None:
        """Everything: the text side plus the image classifier and the ridge map."""
        self._load_text()
        with self._lock:
            if self._net is not None:
                return
            self._set_threads()
            if self.run.runtime == "torch":
                from ._effnet import EffnetLite0

                net: Any = EffnetLite0()
            else:
                from ._effnet_onnx import EffnetLite0Onnx

                net = EffnetLite0Onnx(self.run.threads)
            assert self._bank is not None
            self._ridge = fit_ridge(self._bank, net.classifier_weight)
            self._net = net

    def _set_threads(self) -> None:
        """torch's thread count is process-wide; onnxruntime's is per session (`_onnx.session`)."""
        if self.run.runtime == "torch":
            torch = require("torch", "torch")
            if self.run.threads:
                torch.set_num_threads(self.run.threads)  # type: ignore[attr-defined]

    def classify(self, images: Sequence[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
        """Per-tile class logits (N*tiles, 1000) and pooled features (N*tiles, 1280), image-major."""
        self._load()
        return self.forward(self.tiles(images))

    def tiles(self, images: Sequence[np.ndarray]) -> np.ndarray:
        """The network's input for `images`: (N*tiles, 3, res, res) float32 in [0, 1]."""
        return tile_batch(images, layout(self.config.tiles), self.config.res)

    def forward(self, batch: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The image network alone on a tile batch: logits (n, 1000) and features (n, 1280)."""
        self._load()
        logits, feats = [], []
        for s in range(0, batch.shape[0], MAX_TILES_PER_PASS):
            f, z = self._net(batch[s : s + MAX_TILES_PER_PASS])
            logits.append(z)
            feats.append(f)
        return np.concatenate(logits), np.concatenate(feats)

    def vectors(
        self, logits: np.ndarray, feats: np.ndarray, config: OfflineConfig | None = None
    ) -> np.ndarray:
        """Turn per-tile classifier outputs into one normalised vector per image."""
        cfg = config or self.config
        self._load()
        assert self._bank is not None and self._ridge is not None
        n_tiles = len(layout(cfg.tiles))
        z = logits.reshape(-1, n_tiles, logits.shape[-1]).astype(np.float64)
        sem: np.ndarray | None = None
        if cfg.design in ("conse", "mix", "hybrid"):
            sem = _top_weighted(_pool(_softmax(z / cfg.temp), cfg.pool), cfg.t, self._bank)
        if cfg.design in ("ridge", "mix", "hybrid"):
            f = feats.reshape(-1, n_tiles, feats.shape[-1])
            # features are not probabilities: fmax averages the full frame and the best tiles
            if cfg.pool == "fmax" and n_tiles > 1:
                pooled = 0.5 * f[:, 0] + 0.5 * f[:, 1:].max(axis=1)
            else:
                pooled = _pool(f, cfg.pool)
            r = l2_normalize(pooled @ self._ridge.T)
            sem = r if sem is None else l2_normalize((1.0 - cfg.w) * sem + cfg.w * r)
        if cfg.design == "cls":
            return l2_normalize(np.sqrt(_pool(_softmax(z), cfg.pool)))
        assert sem is not None
        if cfg.design == "hybrid":
            cls = l2_normalize(np.sqrt(_pool(_softmax(z), cfg.pool)))
            return np.hstack([np.sqrt(cfg.a) * sem, np.sqrt(1.0 - cfg.a) * cls]).astype(np.float32)
        return sem

    def embed_images(self, images: Sequence[np.ndarray]) -> np.ndarray:
        if len(images) == 0:
            return np.zeros((0, self.dim), dtype=np.float32)
        logits, feats = self.classify(images)
        return self.vectors(logits, feats)

    def embed_texts(self, texts: Sequence[str], config: OfflineConfig | None = None) -> np.ndarray:
        cfg = config or self.config
        if isinstance(texts, str):
            raise InputError("embed_texts: expected a list of strings, got a single string")
        for i, text in enumerate(texts):
            if not isinstance(text, str):
                raise InputError(f"embed_texts: text {i} is {type(text).__name__}, expected str")
        if len(texts) == 0:
            return np.zeros((0, cfg.dim), dtype=np.float32)
        self._load_text()
        assert self._mu is not None and self._bank is not None
        t = l2_normalize(self._text.encode(list(texts)) - self._mu)
        q = _softmax((t @ self._bank.T).astype(np.float64) / TEXT_TAU)
        if cfg.design == "cls":
            return l2_normalize(q)
        sem = l2_normalize(t + _top_weighted(q, TEXT_TOPK, self._bank))
        if cfg.design == "hybrid":
            return np.hstack([np.sqrt(cfg.a) * sem, np.sqrt(1.0 - cfg.a) * l2_normalize(q)]).astype(
                np.float32
            )
        return sem


def fit_ridge(bank: np.ndarray, weights: np.ndarray, alpha: float = RIDGE_ALPHA) -> np.ndarray:
    """Ridge map M (384, 1280) with bank @ M ~ centred classifier rows.

    Centring the rows is free (softmax ignores a vector added to every row) and removes the
    component that all classes share, which would otherwise dominate every mapped image.
    """
    x = bank.astype(np.float64)
    y = weights.astype(np.float64) - weights.mean(axis=0, keepdims=True)
    m = np.linalg.solve(x.T @ x + alpha * np.eye(x.shape[1]), x.T @ y)
    return m.astype(np.float32)


@EMBEDDERS.register("offline")
def _factory(spec: str, **kwargs: Any) -> OfflineEmbedder:
    cfg, run = parse_spec(spec, **kwargs)
    return OfflineEmbedder(cfg, run)


def label_names() -> list[str]:
    """The offline embedder's label vocabulary (ImageNet's classes, with their synonyms), for
    front ends that describe a frame in words (text-only models)."""
    from ._text import class_names

    return list(class_names())
