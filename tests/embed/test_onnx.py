"""The offline embedder without torch: onnxruntime graphs built from the packaged weights give the
vectors the torch implementation gave (tiles, network, text encoder, whole embedder, a memory
built by the torch path), within float tolerance, and keep text -> frame mAP on the labelled TUM
frames. Comparisons with torch skip where torch (extra `torch`) is not installed."""

from __future__ import annotations

import json
import os
import pickle
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import ravenmem
from ravenmem.embed import _onnx, create_embedder
from ravenmem.embed._torchfile import LEGACY_MAGIC, LEGACY_PROTOCOL, load_state_dict
from ravenmem.embed.offline import OfflineEmbedder, RunOptions
from ravenmem.embed.tiles import layout, tile_batch
from ravenmem.errors import RavenmemError
from ravenmem.types import Frame, Pose
from tests.cli.helpers import run_cli

REPO = Path(__file__).resolve().parents[2]
LABELS = REPO / "benchmarks" / "data" / "tum_labels.json"
FRAMES = ["1305031233.793747.jpg", "1305031238.861826.jpg", "1305031234.861873.jpg", "1305031240.461673.jpg"]
TOL = 2e-5  # vectors are unit rows: the largest coordinate difference allowed


def torch_tiles(images: list[np.ndarray], n_tiles: int, size: int) -> np.ndarray:
    """The tiling that built memories before torch left the core install (torch interpolate)."""
    torch = pytest.importorskip("torch")
    import torch.nn.functional as F

    boxes = layout(n_tiles)
    out = torch.empty((len(images) * len(boxes), 3, size, size), dtype=torch.float32)
    for i, img in enumerate(images):
        h, w = img.shape[:2]
        full = torch.from_numpy(np.array(img)).permute(2, 0, 1).unsqueeze(0).float().div_(255.0)
        for j, (x0, y0, x1, y1) in enumerate(boxes):
            crop = full[
                :,
                :,
                round(y0 * h) : max(round(y1 * h), round(y0 * h) + 1),
                round(x0 * w) : max(round(x1 * w), round(x0 * w) + 1),
            ]
            out[i * len(boxes) + j] = F.interpolate(
                crop, size=(size, size), mode="bilinear", antialias=True, align_corners=False
            )[0]
    return out.clamp_(0.0, 1.0).numpy()


@pytest.fixture(scope="module")
def torch_embedder() -> OfflineEmbedder:
    pytest.importorskip("torch")
    emb = OfflineEmbedder(run=RunOptions(runtime="torch"))
    emb.embed_texts(["warm-up"])
    return emb


def test_state_dict_reader_equals_torch_load(tmp_path: Path) -> None:
    torch = pytest.importorskip("torch")
    from ravenmem.embed._effnet_onnx import weights_path

    shipped = torch.load(weights_path(), map_location="cpu", weights_only=True)  # the legacy format
    ours = load_state_dict(weights_path())
    assert list(ours) == list(shipped) and len(ours) == 296
    for k, v in shipped.items():
        assert ours[k].dtype == v.numpy().dtype and np.array_equal(ours[k], v.numpy()), k
    odd = {
        "t": torch.arange(12.0).reshape(3, 4).t(),
        "view": torch.arange(10)[2:5],
        "h": torch.ones(2).half(),
    }
    torch.save(odd, tmp_path / "zip.pt")  # today's zip format, strided and offset tensors
    got = load_state_dict(tmp_path / "zip.pt")
    for k, v in odd.items():
        assert np.array_equal(got[k], v.numpy()) and got[k].dtype == v.numpy().dtype, k


class _Evil:
    def __reduce__(self):
        return (os.system, ("echo pwned",))


def test_state_dict_reader_refuses_anything_but_tensors(tmp_path: Path) -> None:
    bad = tmp_path / "evil.pth"
    with bad.open("wb") as f:
        for part in (LEGACY_MAGIC, LEGACY_PROTOCOL, {"little_endian": True}, {"w": _Evil()}, []):
            pickle.dump(part, f, protocol=2)
    with pytest.raises(RavenmemError, match="refusing to load posix.system|refusing to load os.system"):
        load_state_dict(bad)
    (tmp_path / "junk.pth").write_bytes(b"not a pickle at all")
    with pytest.raises(RavenmemError, match="not a readable torch state dict"):
        load_state_dict(tmp_path / "junk.pth")


@pytest.mark.parametrize("n_tiles", [1, 5, 10])
def test_tiles_equal_torch_interpolate(tum_frame, n_tiles: int) -> None:
    rng = np.random.default_rng(0)
    images = [tum_frame(FRAMES[0]), rng.integers(0, 256, (37, 53, 3), dtype=np.uint8)]
    for size in (224, 96):
        np.testing.assert_allclose(
            tile_batch(images, layout(n_tiles), size), torch_tiles(images, n_tiles, size), atol=2e-5
        )


def test_network_equals_torch(tum_frame) -> None:
    pytest.importorskip("torch")
    from ravenmem.embed._effnet import EffnetLite0
    from ravenmem.embed._effnet_onnx import EffnetLite0Onnx

    batch = tile_batch([tum_frame(n) for n in FRAMES[:2]], layout(5), 224)
    (tf, tz), (of, oz) = EffnetLite0()(batch), EffnetLite0Onnx(threads=1)(batch)
    np.testing.assert_allclose(of, tf, atol=2e-4, rtol=1e-4)
    np.testing.assert_allclose(oz, tz, atol=2e-4, rtol=1e-4)
    assert (oz.argmax(1) == tz.argmax(1)).all()


def test_vectors_equal_the_torch_path_on_tum_frames_and_label_texts(
    offline, torch_embedder, tum_frame
) -> None:
    """The default (onnxruntime) embedder against the torch implementation as it was: torch tiles,
    torch network, torch MiniLM, on real frames and on every query and class phrasing tested."""
    images = [tum_frame(n) for n in FRAMES]
    old = torch_embedder.vectors(*torch_embedder.forward(torch_tiles(images, 5, 224)))
    new = offline.embed_images(images)
    assert offline.name == torch_embedder.name  # one identity: same vectors within tolerance
    np.testing.assert_allclose(new, old, atol=TOL)
    queries = list(json.loads(LABELS.read_text())["queries"].values())
    texts = [*queries, *(f"a photo of a {q}." for q in queries), "", "room 214 " * 100]
    np.testing.assert_allclose(offline.embed_texts(texts), torch_embedder.embed_texts(texts), atol=TOL)


def test_text_to_frame_map_unchanged(offline, tum_labels) -> None:
    """mAP over the 91 labelled TUM frames within 0.01 of the torch path's 0.761 (docs/measured.md)."""
    from ravenmem.eval.retrieval import (
        MIN_POSITIVES,
        load_images,
        load_labels,
        summarize_direction,
        text_to_image,
    )
    from tests.embed.conftest import TUM

    labels = load_labels(LABELS)
    objects = labels.objects(MIN_POSITIVES)
    images = load_images(labels, TUM / "rgb")
    vecs = np.concatenate([offline.embed_images(images[s : s + 16]) for s in range(0, len(images), 16)])
    queries = offline.embed_texts([labels.queries[o] for o in objects])
    small = np.array([o in labels.small for o in objects])
    m = summarize_direction(text_to_image(vecs, queries, labels.truth(objects), k=5), small)
    assert abs(m["mAP"] - 0.761) <= 0.01, m


def test_a_memory_built_by_the_torch_path_opens_and_searches_without_torch(
    tmp_path: Path, torch_embedder, tum_frame
) -> None:
    frames = [
        Frame(image=tum_frame(n), t=1305031229.0 + 10 * i, pose=Pose(0.1 * i, 0.0), source="tum", index=i)
        for i, n in enumerate(FRAMES)
    ]
    path = tmp_path / "torch.mem"
    with ravenmem.create(path, embedder=torch_embedder, ocr=False, thumb_size=0) as mem:
        mem.add_frames(frames)
        want = [(h.memory.id, h.score) for h in mem.search_text("a computer keyboard", k=4)]
    # the real command, with torch made unimportable: the stored name rebuilds the onnx embedder
    block = tmp_path / "block"
    block.mkdir()
    (block / "torch.py").write_text("raise ImportError('torch is blocked in this test')\n")
    r = run_cli("search", "a computer keyboard", "-m", str(path), "-k", "4", "--json", paths=(block,))
    assert r.returncode == 0, r.stderr
    got = [(h["id"], h["score"]) for h in json.loads(r.stdout)["results"]]
    assert want and [i for i, _ in got] == [i for i, _ in want]
    np.testing.assert_allclose([s for _, s in got], [s for _, s in want], atol=1e-4)


def test_graphs_are_built_once_into_the_user_cache(tmp_path: Path, offline) -> None:
    """First use builds both graphs under $RAVENMEM_CACHE_DIR/onnx (not in the memory), later
    processes reuse them, a damaged cache file is rebuilt, and torch is never imported."""
    from ravenmem.embed.base import cache_dir

    code = (
        "import sys, numpy as np\n"
        "from ravenmem.embed import create_embedder\n"
        "e = create_embedder('offline:tiles=1:threads=1')\n"
        "v = e.embed_images([np.full((48, 64, 3), 128, np.uint8)]); t = e.embed_texts(['a mug'])\n"
        "print(float(v[0] @ t[0]), 'torch' in sys.modules, 'sentence_transformers' in sys.modules)\n"
    )
    cache = tmp_path / "cache"
    cache.mkdir()
    for bank in cache_dir().glob("label-bank-*.npy"):  # built by the `offline` fixture: not rebuilt here
        (cache / bank.name).write_bytes(bank.read_bytes())
    env = dict(os.environ, PYTHONPATH=str(REPO / "src"), RAVENMEM_CACHE_DIR=str(cache))

    def run() -> tuple[str, list[Path]]:
        r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=300)
        assert r.returncode == 0, r.stderr
        return r.stdout, sorted((cache / "onnx").glob("*.onnx"))

    out1, files = run()
    assert [f.name.split("-")[0] for f in files] == ["effnet", "minilm"], files
    assert out1.split()[1:] == ["False", "False"]
    stamps = [f.stat().st_mtime_ns for f in files]
    out2, again = run()
    assert again == files and [f.stat().st_mtime_ns for f in again] == stamps and out2 == out1
    files[0].write_bytes(b"damaged")
    out3, rebuilt = run()
    assert out3 == out1 and rebuilt[0].stat().st_size > 1_000_000


def test_the_torch_runtime_without_torch_names_the_extra(tmp_path: Path) -> None:
    block = tmp_path / "block"
    block.mkdir()
    (block / "torch.py").write_text("raise ImportError('torch is blocked in this test')\n")
    code = "from ravenmem.embed import create_embedder\ncreate_embedder('offline:runtime=torch').embed_texts(['a'])\n"
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(block), str(REPO / "src")]))
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=120)
    assert r.returncode != 0 and "pip install 'ravenmem[torch]'" in r.stderr, r.stderr[-2000:]


def test_threads_default_and_override(monkeypatch) -> None:
    monkeypatch.delenv("RAVENMEM_THREADS", raising=False)
    assert _onnx.default_threads() == max(1, min(_onnx.MAX_DEFAULT_THREADS, os.cpu_count() or 1))
    monkeypatch.setenv("RAVENMEM_THREADS", "1")
    assert _onnx.default_threads() == 1
    monkeypatch.setenv("RAVENMEM_THREADS", "many")
    with pytest.raises(RavenmemError, match="RAVENMEM_THREADS"):
        _onnx.default_threads()
    emb = create_embedder("offline:threads=1")
    assert emb.run.threads == 1  # type: ignore[attr-defined]
