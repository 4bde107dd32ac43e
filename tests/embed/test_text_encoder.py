"""The fast paths give the same numbers as the slow ones they replaced: MiniLM through
onnxruntime and through plain torch vs sentence-transformers, folded batch norms vs the plain
network; and creating an embedder loads nothing."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from ravenmem.embed._text import MiniLM

REPO = Path(__file__).resolve().parents[2]
TEXTS = [
    "a computer keyboard",
    "  Leading and trailing spaces, UPPER case!  ",
    "",
    "a photo of a café, naïve résumé",
    "数字 中文 mixed with English",
    "tab\tand\nnewline",
    "room 214 " * 200,  # longer than the model's 256 tokens: truncated the same way
    *[f"a photo of a {w}." for w in ("joystick", "coffee mug", "monitor", "desk", "swivel chair")],
]


@pytest.mark.parametrize("runtime", ["onnx", "torch"])
def test_minilm_vectors_equal_sentence_transformers(runtime: str) -> None:
    st = pytest.importorskip("sentence_transformers")
    ours = MiniLM(runtime)
    ref = st.SentenceTransformer(str(ours.path), device="cpu")
    want = ref.encode(TEXTS, batch_size=4, convert_to_numpy=True, normalize_embeddings=True)
    got = ours.encode(TEXTS, batch_size=4)
    assert got.shape == want.shape == (len(TEXTS), 384) and got.dtype == np.float32
    np.testing.assert_allclose(got, want, atol=2e-6)
    # batching (and so padding) does not change a vector
    np.testing.assert_allclose(ours.encode(TEXTS[:1]), got[:1], atol=2e-6)


def test_folded_network_equals_the_plain_one(tum_frame) -> None:
    torch = pytest.importorskip("torch")

    from ravenmem.embed._effnet import EffnetLite0
    from ravenmem.embed.tiles import layout, tile_batch

    batch = tile_batch([tum_frame("1305031233.793747.jpg")], layout(5), 224)
    (pf, pz), (ff, fz) = EffnetLite0(fold=False)(batch), EffnetLite0()(batch)
    assert not any(isinstance(m, torch.nn.BatchNorm2d) for m in EffnetLite0().model.modules())
    np.testing.assert_allclose(fz, pz, atol=2e-4, rtol=1e-4)
    np.testing.assert_allclose(ff, pf, atol=2e-4, rtol=1e-4)
    assert bool((fz.argmax(1) == pz.argmax(1)).all())


def test_creating_an_embedder_loads_nothing() -> None:
    """`create_embedder(spec)` gives `name` and `dim` without torch, onnxruntime or any weights
    (reopening a memory compares names; a server creates it once and loads on first use)."""
    code = (
        "import sys\n"
        "from ravenmem.embed import create_embedder\n"
        "e = create_embedder('offline:design=hybrid')\n"
        "print(e.name, e.dim, 'torch' in sys.modules or 'onnxruntime' in sys.modules)\n"
    )
    env = dict(os.environ, PYTHONPATH=str(REPO / "src"))
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=120)
    assert r.returncode == 0, r.stderr
    assert r.stdout.split() == [
        "offline:effnet-lite0+minilm:hybrid-t100-temp3-w0.3-a0.7:tiles5-fmax:r224",
        "1384",
        "False",
    ]
