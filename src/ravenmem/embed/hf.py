"""Hugging Face transformers backend (extra `hf`): CLIP, SigLIP, SigLIP 2 and other dual encoders.

Spec: `hf:NAME_OR_LOCAL_FOLDER`, e.g. `hf:/models/siglip2-base-patch16-224` (offline: a folder
written by `save_pretrained` holding the model and its processor) or `hf:google/siglip-base-patch16-224`
(downloaded once into the hub cache; set HF_HUB_OFFLINE=1 to forbid downloads; a model that cannot
be loaded, e.g. without network, is one `InputError`). The model must offer
`get_image_features` and `get_text_features`; transformers >= 5 returns an output object whose
`pooler_output` holds the projected embedding, older versions a tensor: both are handled.
Keyword `device` picks where it runs; it does not change the name.
"""

from __future__ import annotations

import inspect
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import InputError, one_line, require
from ._lazy import LazyTorchEmbedder
from .base import EMBEDDERS, l2_normalize

# SigLIP families were trained on texts padded to the full context; CLIP pads to the longest
PAD_TO_MAX = ("siglip", "siglip2")


def _features(out: Any) -> Any:
    """The embedding tensor from whatever get_*_features returned."""
    if hasattr(out, "pooler_output") and out.pooler_output is not None:
        return out.pooler_output
    if isinstance(out, (tuple, list)):
        return out[1] if len(out) > 1 else out[0]
    return out


def _accepted(fn: Any, inputs: dict[str, Any]) -> dict[str, Any]:
    """Keep the processor outputs that `fn` takes (e.g. SigLIP 2's spatial_shapes, pixel masks)."""
    params = inspect.signature(fn).parameters
    if any(p.kind is inspect.Parameter.VAR_KEYWORD for p in params.values()) and not any(
        k in params for k in inputs
    ):
        return dict(inputs)
    return {k: v for k, v in inputs.items() if k in params}


class HFEmbedder(LazyTorchEmbedder):
    """Loads lazily on first use; runs in fp32 on `device` (default: cuda if available)."""

    def __init__(self, spec: str, device: str | None = None) -> None:
        super().__init__(device)
        spec = spec.strip()
        if not spec:
            raise InputError("hf embedder: give a model folder or hub name, e.g. hf:/models/siglip2-base")
        path = Path(spec).expanduser()
        looks_local = spec.startswith((".", "/", "~")) or path.exists()
        if looks_local and not path.is_dir():
            raise InputError(f"hf embedder: model folder {path} not found")
        self.source = str(path.resolve()) if looks_local else spec
        self._model: Any = None
        self._processor: Any = None

    @property
    def name(self) -> str:
        return f"hf:{self.source}"

    def _reachable(self) -> None:
        """A hub name's config is fetched (or found in the cache) before torch and transformers
        are imported: a model that cannot be had (unknown, no network, offline and not cached)
        is one `InputError` in a fraction of a second, not after seconds of imports."""
        if Path(self.source).is_dir():
            return
        hub: Any = require("huggingface_hub", "hf")
        try:
            hub.hf_hub_download(self.source, "config.json")
        except Exception as e:  # not found, no network, offline without a cached copy
            raise self._cannot_load(e) from None

    def _cannot_load(self, e: Exception) -> InputError:
        """The one-line error for a model that could not be had, with the library's reason."""
        reason = one_line(e) or type(e).__name__
        return InputError(f"hf embedder: cannot load {self.source!r}: {reason}")

    def _load_model(self) -> int:
        self._reachable()
        torch: Any = require("torch", "hf")  # before transformers: it installs without torch
        tf: Any = require("transformers", "hf")

        device = self.device or ("cuda" if torch.cuda.is_available() else "cpu")
        try:
            model = tf.AutoModel.from_pretrained(self.source)
            if not (hasattr(model, "get_image_features") and hasattr(model, "get_text_features")):
                raise InputError(
                    f"hf embedder: {self.source} ({type(model).__name__}) is not an image-text dual encoder"
                )
            self._processor = tf.AutoProcessor.from_pretrained(self.source)
        except (OSError, ValueError) as e:  # not found, no network (downloads retry first), bad folder
            raise self._cannot_load(e) from None
        self._model = model.to(device).eval()
        self.device = device
        return int(self._encode_texts(["a"]).shape[-1])

    def _encode_texts(self, texts: list[str]) -> np.ndarray:
        import torch

        model_type = getattr(self._model.config, "model_type", "")
        if model_type in PAD_TO_MAX:
            max_len = getattr(getattr(self._model.config, "text_config", None), "max_position_embeddings", 64)
            pad: dict[str, Any] = {"padding": "max_length", "max_length": max_len}
        else:
            pad = {"padding": True}
        inputs = self._processor(text=texts, return_tensors="pt", truncation=True, **pad)
        inputs = {
            k: v.to(self.device) for k, v in _accepted(self._model.get_text_features, dict(inputs)).items()
        }
        with torch.inference_mode():
            feats = _features(self._model.get_text_features(**inputs))
        return l2_normalize(feats.float().cpu().numpy())

    def _encode_images(self, images: list[np.ndarray]) -> np.ndarray:
        import torch

        inputs = self._processor(images=images, return_tensors="pt")
        inputs = {
            k: v.to(self.device) for k, v in _accepted(self._model.get_image_features, dict(inputs)).items()
        }
        with torch.inference_mode():
            feats = _features(self._model.get_image_features(**inputs))
        return l2_normalize(feats.float().cpu().numpy())


@EMBEDDERS.register("hf")
def _factory(spec: str, device: str | None = None) -> HFEmbedder:
    return HFEmbedder(spec, device=device)
