"""The open_clip backend, end to end through create_embedder, on a tiny random model saved here."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from ravenmem.embed import create_embedder
from ravenmem.errors import InputError

open_clip = pytest.importorskip("open_clip", reason="open_clip not installed (extra 'clip')")
torch = pytest.importorskip("torch")

TINY = {
    "embed_dim": 16,
    "vision_cfg": {"image_size": 32, "layers": 2, "width": 32, "patch_size": 8, "head_width": 16},
    "text_cfg": {"context_length": 16, "vocab_size": 49408, "width": 32, "heads": 2, "layers": 2},
}


@pytest.fixture(scope="module")
def tiny_checkpoint(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """A model-config JSON and a checkpoint of a randomly initialised tiny CLIP, in open_clip's format."""
    d = tmp_path_factory.mktemp("oc")
    cfg = d / "ravenmem-tiny-vit.json"
    cfg.write_text(json.dumps(TINY))
    open_clip.add_model_config(cfg)
    torch.manual_seed(0)
    model = open_clip.create_model("ravenmem-tiny-vit", pretrained=None)
    ckpt = d / "tiny.pt"
    torch.save({"epoch": 1, "state_dict": model.state_dict()}, ckpt)
    return cfg, ckpt


def _images() -> list[np.ndarray]:
    rng = np.random.default_rng(0)
    return [rng.integers(0, 256, (48, 64, 3), dtype=np.uint8), np.full((40, 40, 3), 200, np.uint8)]


def test_tiny_checkpoint_loads_through_the_public_path(tiny_checkpoint: tuple[Path, Path]) -> None:
    cfg, ckpt = tiny_checkpoint
    e = create_embedder(f"open_clip:{cfg}@{ckpt}", device="cpu")
    assert e.name == f"open_clip:{cfg.resolve()}@{ckpt.resolve()}"
    assert e.dim == 16
    imgs = e.embed_images(_images())
    txts = e.embed_texts(["a red mug", "a computer keyboard", ""])
    assert imgs.shape == (2, 16) and txts.shape == (3, 16)
    assert imgs.dtype == np.float32 and txts.dtype == np.float32
    np.testing.assert_allclose(np.linalg.norm(imgs, axis=1), 1.0, atol=1e-5)
    np.testing.assert_allclose(np.linalg.norm(txts, axis=1), 1.0, atol=1e-5)
    assert not np.allclose(imgs[0], imgs[1]) and not np.allclose(txts[0], txts[1])
    np.testing.assert_array_equal(imgs, e.embed_images(_images()))  # deterministic
    assert e.embed_images([]).shape == (0, 16) and e.embed_texts([]).shape == (0, 16)

    # a stored name rebuilds the same embedder: identical vectors from the reloaded checkpoint
    again = create_embedder(e.name, device="cpu")
    np.testing.assert_array_equal(again.embed_images(_images()), imgs)
    np.testing.assert_array_equal(again.embed_texts(["a red mug", "a computer keyboard", ""]), txts)


def test_vectors_come_from_the_checkpoint_weights(tiny_checkpoint: tuple[Path, Path], tmp_path: Path) -> None:
    cfg, ckpt = tiny_checkpoint
    torch.manual_seed(1)
    other = open_clip.create_model("ravenmem-tiny-vit", pretrained=None)
    ckpt2 = tmp_path / "other.pt"
    torch.save(other.state_dict(), ckpt2)  # a bare state dict works too
    a = create_embedder(f"open_clip:{cfg}@{ckpt}", device="cpu").embed_texts(["a red mug"])
    b = create_embedder(f"open_clip:{cfg}@{ckpt2}", device="cpu").embed_texts(["a red mug"])
    assert not np.allclose(a, b)


def test_spec_errors(tmp_path: Path) -> None:
    ckpt = tmp_path / "x.pt"
    ckpt.write_bytes(b"")
    with pytest.raises(InputError, match="checkpoint"):
        create_embedder(f"open_clip:ViT-B-32@{tmp_path / 'missing.pt'}")
    with pytest.raises(InputError, match="model config"):
        create_embedder(f"open_clip:{tmp_path / 'missing.json'}@{ckpt}")
    with pytest.raises(InputError, match="MODEL/PRETRAINED"):
        create_embedder("open_clip:")
    with pytest.raises(InputError, match="unknown model"):
        create_embedder(f"open_clip:No-Such-Model@{ckpt}").embed_texts(["x"])


def test_pretrained_tag_is_parsed_without_loading() -> None:
    e = create_embedder("open_clip:ViT-B-32/laion2b_s34b_b79k")
    assert e.name == "open_clip:ViT-B-32/laion2b_s34b_b79k"
    assert (e.model_name, e.pretrained) == ("ViT-B-32", "laion2b_s34b_b79k")  # type: ignore[attr-defined]
