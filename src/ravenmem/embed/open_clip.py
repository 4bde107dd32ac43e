"""OpenCLIP backend (extra `clip`): any open_clip model, by pretrained tag or local checkpoint.

Specs:
- `open_clip:MODEL/PRETRAINED`, e.g. `open_clip:ViT-B-32/laion2b_s34b_b79k` (open_clip fetches
  the weights into its cache the first time; offline machines pre-populate that cache);
- `open_clip:MODEL@/path/to/checkpoint.pt`: weights from a local file (a state dict, optionally
  under a `state_dict` key, as open_clip saves them);
- MODEL may be a path to a model-config JSON (`/path/to/my-model.json`), registered with open_clip
  under its file stem, for custom architectures;
- `open_clip:hf-hub:ORG/REPO`: a Hugging Face hub model with its config and weights.
Keyword `device` ("cpu", "cuda", ...) picks where it runs; it does not change the name.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from ..errors import InputError, require
from ._lazy import LazyTorchEmbedder
from .base import EMBEDDERS, l2_normalize


def parse_spec(spec: str) -> tuple[str, str | None, Path | None, Path | None]:
    """-> (model name, pretrained tag, checkpoint path, model-config JSON path)."""
    spec = spec.strip()
    if not spec:
        raise InputError("open_clip embedder: give MODEL/PRETRAINED or MODEL@/path/to/checkpoint.pt")
    if spec.startswith("hf-hub:"):
        return spec, None, None, None
    model, ckpt, pretrained = spec, None, None
    if "@" in spec:
        model, _, c = spec.partition("@")
        ckpt = Path(c).expanduser().resolve()
        if not ckpt.is_file():
            raise InputError(f"open_clip embedder: checkpoint {ckpt} not found")
    elif not spec.endswith(".json") and "/" in spec:
        model, _, pretrained = spec.rpartition("/")
    config = None
    if model.endswith(".json"):
        config = Path(model).expanduser().resolve()
        if not config.is_file():
            raise InputError(f"open_clip embedder: model config {config} not found")
        model = config.stem
    if not model:
        raise InputError(f"open_clip embedder: no model name in {spec!r}")
    return model, pretrained, ckpt, config


class OpenClipEmbedder(LazyTorchEmbedder):
    """Loads lazily (the first embed or `dim` access) and runs in fp32 on `device`."""

    def __init__(self, spec: str, device: str | None = None) -> None:
        super().__init__(device)
        self.model_name, self.pretrained, self.checkpoint, self.config_path = parse_spec(spec)
        self._model: Any = None
        self._preprocess: Any = None
        self._tokenizer: Any = None

    @property
    def name(self) -> str:
        model = str(self.config_path) if self.config_path else self.model_name
        if self.checkpoint is not None:
            return f"open_clip:{model}@{self.checkpoint}"
        if self.pretrained:
            return f"open_clip:{model}/{self.pretrained}"
        return f"open_clip:{model}"

    def _load_model(self) -> int:
        torch: Any = require("torch", "clip")  # before open_clip: it installs without torch
        oc: Any = require("open_clip", "clip")

        if self.config_path is not None:
            oc.add_model_config(self.config_path)
        if self.model_name not in oc.list_models() and not self.model_name.startswith("hf-hub:"):
            raise InputError(
                f"open_clip embedder: unknown model {self.model_name!r} (see open_clip.list_models())"
            )
        device = self.device or ("cuda" if torch.cuda.is_available() else "cpu")
        weights = str(self.checkpoint) if self.checkpoint is not None else self.pretrained
        model, _, preprocess = oc.create_model_and_transforms(
            self.model_name, pretrained=weights, device=device
        )
        model.eval()
        self._tokenizer = oc.get_tokenizer(self.model_name)
        self._preprocess = preprocess
        self.device = device
        with torch.inference_mode():
            probe = model.encode_text(self._tokenizer(["a"]).to(device))
        self._model = model
        return int(probe.shape[-1])

    def _encode_images(self, images: list[np.ndarray]) -> np.ndarray:
        import torch
        from PIL import Image

        batch = torch.stack([self._preprocess(Image.fromarray(im)) for im in images])
        with torch.inference_mode():
            feats = self._model.encode_image(batch.to(self.device))
        return l2_normalize(feats.float().cpu().numpy())

    def _encode_texts(self, texts: list[str]) -> np.ndarray:
        import torch

        with torch.inference_mode():
            feats = self._model.encode_text(self._tokenizer(texts).to(self.device))
        return l2_normalize(feats.float().cpu().numpy())


@EMBEDDERS.register("open_clip")
def _factory(spec: str, device: str | None = None) -> OpenClipEmbedder:
    return OpenClipEmbedder(spec, device=device)
