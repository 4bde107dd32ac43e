"""The transformers backend on tiny random CLIP, SigLIP and SigLIP 2 models saved locally here."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from ravenmem.embed import create_embedder
from ravenmem.errors import InputError

transformers = pytest.importorskip("transformers", reason="transformers not installed (extra 'hf')")
torch = pytest.importorskip("torch")
tokenizers = pytest.importorskip("tokenizers")

TINY_TOWER = {"hidden_size": 32, "intermediate_size": 37, "num_hidden_layers": 2, "num_attention_heads": 4}
WORDS = ["<pad>", "</s>", "<unk>", "a", "red", "mug", "computer", "keyboard", "photo", "of"]


def _clip_tokenizer(d: Path):
    """A real CLIP BPE tokenizer with a tiny vocabulary (single characters, no merges)."""
    chars = [chr(c) for c in range(ord("a"), ord("z") + 1)] + [str(i) for i in range(10)]
    vocab = {"<|startoftext|>": 0, "<|endoftext|>": 1}
    for suffix in ("", "</w>"):
        vocab.update({c + suffix: len(vocab) + i for i, c in enumerate(chars)})
    (d / "vocab.json").write_text(json.dumps(vocab))
    (d / "merges.txt").write_text("#version: 0.2\n")
    return transformers.CLIPTokenizer.from_pretrained(str(d)), len(vocab)


def _word_tokenizer(max_len: int):
    """A word-level tokenizer built with the `tokenizers` library (SigLIP's is sentencepiece)."""
    tk = tokenizers.Tokenizer(
        tokenizers.models.WordLevel({w: i for i, w in enumerate(WORDS)}, unk_token="<unk>")
    )
    tk.normalizer = tokenizers.normalizers.Lowercase()
    tk.pre_tokenizer = tokenizers.pre_tokenizers.Whitespace()
    tk.post_processor = tokenizers.processors.TemplateProcessing(
        single="$A </s>", special_tokens=[("</s>", 1)]
    )
    return transformers.PreTrainedTokenizerFast(
        tokenizer_object=tk, pad_token="<pad>", eos_token="</s>", unk_token="<unk>", model_max_length=max_len
    )


@pytest.fixture(scope="module")
def clip_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    d = tmp_path_factory.mktemp("clip")
    tok, vocab_size = _clip_tokenizer(d)
    cfg = transformers.CLIPConfig(
        text_config={
            **TINY_TOWER,
            "vocab_size": vocab_size,
            "max_position_embeddings": 32,
            "bos_token_id": 0,
            "eos_token_id": 1,
            "pad_token_id": 1,
        },
        vision_config={**TINY_TOWER, "image_size": 32, "patch_size": 8},
        projection_dim=16,
    )
    torch.manual_seed(0)
    model = transformers.CLIPModel(cfg)
    proc = transformers.CLIPProcessor(
        image_processor=transformers.CLIPImageProcessor(
            size={"shortest_edge": 32}, crop_size={"height": 32, "width": 32}
        ),
        tokenizer=tok,
    )
    out = d / "tiny-clip"
    model.save_pretrained(out)
    proc.save_pretrained(out)
    return out


@pytest.fixture(scope="module")
def siglip_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    d = tmp_path_factory.mktemp("siglip")
    cfg = transformers.SiglipConfig(
        text_config={**TINY_TOWER, "vocab_size": len(WORDS), "max_position_embeddings": 16},
        vision_config={**TINY_TOWER, "image_size": 32, "patch_size": 8},
    )
    torch.manual_seed(0)
    model = transformers.SiglipModel(cfg)
    proc = transformers.SiglipProcessor(
        image_processor=transformers.SiglipImageProcessor(size={"height": 32, "width": 32}),
        tokenizer=_word_tokenizer(16),
    )
    model.save_pretrained(d)
    proc.save_pretrained(d)
    return d


@pytest.fixture(scope="module")
def siglip2_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    d = tmp_path_factory.mktemp("siglip2")
    # the SigLIP 2 processor defaults to 16-px patches and up to 256 of them (NaFlex)
    cfg = transformers.Siglip2Config(
        text_config={**TINY_TOWER, "vocab_size": len(WORDS), "max_position_embeddings": 16},
        vision_config={**TINY_TOWER, "num_patches": 256, "patch_size": 16},
    )
    torch.manual_seed(0)
    model = transformers.Siglip2Model(cfg)
    proc = transformers.Siglip2Processor(
        image_processor=transformers.Siglip2ImageProcessor(patch_size=16, max_num_patches=256),
        tokenizer=_word_tokenizer(16),
    )
    model.save_pretrained(d)
    proc.save_pretrained(d)
    return d


def _images() -> list[np.ndarray]:
    rng = np.random.default_rng(0)
    return [rng.integers(0, 256, (48, 64, 3), dtype=np.uint8), np.full((40, 30, 3), 90, np.uint8)]


@pytest.mark.parametrize("which, dim", [("clip_dir", 16), ("siglip_dir", 32), ("siglip2_dir", 32)])
def test_tiny_model_loads_from_local_folder(which: str, dim: int, request: pytest.FixtureRequest) -> None:
    folder: Path = request.getfixturevalue(which)
    e = create_embedder(f"hf:{folder}", device="cpu")
    assert e.name == f"hf:{folder.resolve()}"
    assert e.dim == dim
    imgs = e.embed_images(_images())
    txts = e.embed_texts(["a red mug", "a computer keyboard"])
    assert imgs.shape == (2, dim) and txts.shape == (2, dim)
    assert imgs.dtype == np.float32 and txts.dtype == np.float32
    np.testing.assert_allclose(np.linalg.norm(imgs, axis=1), 1.0, atol=1e-5)
    np.testing.assert_allclose(np.linalg.norm(txts, axis=1), 1.0, atol=1e-5)
    assert not np.allclose(imgs[0], imgs[1]) and not np.allclose(txts[0], txts[1])
    np.testing.assert_array_equal(imgs, e.embed_images(_images()))
    assert e.embed_images([]).shape == (0, dim) and e.embed_texts([]).shape == (0, dim)
    # the stored name rebuilds an embedder that gives the same vectors
    again = create_embedder(e.name, device="cpu")
    np.testing.assert_allclose(again.embed_texts(["a red mug", "a computer keyboard"]), txts, atol=1e-6)
    np.testing.assert_allclose(again.embed_images(_images()), imgs, atol=1e-6)


def test_siglip_pads_texts_to_full_context(siglip_dir: Path) -> None:
    """SigLIP is trained on max-length padding: a text's vector must not depend on its batch mates."""
    e = create_embedder(f"hf:{siglip_dir}", device="cpu")
    alone = e.embed_texts(["a mug"])
    batched = e.embed_texts(["a mug", "a red computer keyboard photo of a mug"])
    np.testing.assert_allclose(alone[0], batched[0], atol=1e-5)


def test_errors(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="not found"):
        create_embedder(f"hf:{tmp_path / 'nope'}")
    with pytest.raises(InputError, match="model folder"):
        create_embedder("hf:")
    e = create_embedder(f"hf:{tmp_path}")
    with pytest.raises(InputError, match="list of strings"):
        e.embed_texts("a mug")  # type: ignore[arg-type]
