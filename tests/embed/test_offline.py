"""The offline embedder on real TUM frames: shapes, normalisation, names, retrieval, tiles."""

from __future__ import annotations

import numpy as np
import pytest
from PIL import Image

from ravenmem.embed import Embedder, create_embedder
from ravenmem.embed.offline import OfflineConfig, RunOptions, parse_spec
from ravenmem.errors import InputError

KEYBOARD = ["1305031233.793747.jpg", "1305031238.861826.jpg", "1305031241.793694.jpg"]  # frames 128, 280, 368
NO_KEYBOARD = ["1305031234.861873.jpg", "1305031237.529735.jpg", "1305031240.461673.jpg"]  # 160, 240, 328


def test_frame_names_match_labels(tum_labels: dict[str, list[str]]) -> None:
    assert all("keyboard" in tum_labels[n] for n in KEYBOARD)
    assert all("keyboard" not in tum_labels[n] for n in NO_KEYBOARD)


def test_shapes_normalisation_and_determinism(offline: Embedder, tum_frame) -> None:
    imgs = [tum_frame(n) for n in KEYBOARD[:2]]
    a = offline.embed_images(imgs)
    assert isinstance(offline, Embedder)
    assert a.shape == (2, offline.dim) and a.dtype == np.float32
    np.testing.assert_allclose(np.linalg.norm(a, axis=1), 1.0, atol=1e-5)
    assert not np.allclose(a[0], a[1])
    b = offline.embed_images(imgs[:1])
    np.testing.assert_allclose(a[:1], b, atol=1e-5)  # same image, other batch: same vector
    np.testing.assert_array_equal(b, offline.embed_images(imgs[:1]))
    t = offline.embed_texts(["a computer keyboard", "a coffee mug"])
    assert t.shape == (2, offline.dim) and t.dtype == np.float32
    np.testing.assert_allclose(np.linalg.norm(t, axis=1), 1.0, atol=1e-5)
    assert offline.embed_images([]).shape == (0, offline.dim)
    assert offline.embed_texts([]).shape == (0, offline.dim)


def test_default_name_is_explicit_and_small_enough(offline: Embedder) -> None:
    assert offline.name.startswith("offline:effnet-lite0+minilm:")
    assert "tiles5" in offline.name
    assert offline.dim * 4 <= 8192  # float32 bytes per memory within the 8 KB target


@pytest.mark.parametrize(
    "spec",
    [
        "offline",
        "offline:tiles=none",
        "offline:design=conse:t=10:temp=1",
        "offline:design=ridge:tiles=6:pool=max",
        "offline:design=mix:w=0.25:res=192",
        "offline:design=cls",
        "offline:design=hybrid:a=0.5:tiles=10:pool=mean",
    ],
)
def test_name_round_trips(spec: str) -> None:
    e = create_embedder(spec)
    again = create_embedder(e.name)
    assert again.name == e.name
    assert again.config == e.config  # type: ignore[attr-defined]
    assert again.dim == e.dim


def test_spec_forms() -> None:
    cfg, run = parse_spec("tiles=none:threads=2")
    assert cfg.tiles == 1 and run == RunOptions(threads=2, runtime="onnx")
    cfg, run = parse_spec("runtime=torch")
    assert cfg == OfflineConfig() and run.runtime == "torch" and run.threads is None
    cfg, _ = parse_spec("effnet-lite0+minilm:conse-t7-temp0.5:tiles6-max:r160")
    assert cfg == OfflineConfig(design="conse", t=7, temp=0.5, tiles=6, pool="max", res=160)
    assert parse_spec("", design="cls")[0].dim == 1000
    assert parse_spec("design=mix")[0].dim == 384
    assert parse_spec("temp=0.3333333333")[0].temp == 0.333333  # quantised to what the name prints


@pytest.mark.parametrize(
    "spec, match",
    [
        ("offline:bogus", "unknown option 'bogus'"),
        ("offline:design=clip", "design="),
        ("offline:tiles=7", "tiles=7"),
        ("offline:t=abc", "not a valid int"),
        ("offline:w=2", "w=2"),
        ("offline:color=red", "unknown option 'color'"),
        ("offline:conse-x", "bad design option"),
        ("offline:runtime=tensorflow", "runtime='tensorflow'"),
        ("offline:threads=0", "threads=0"),
    ],
)
def test_bad_specs_raise_input_error(spec: str, match: str) -> None:
    with pytest.raises(InputError, match=match):
        create_embedder(spec)


def test_recreated_embedder_gives_identical_vectors(offline: Embedder, tum_frame) -> None:
    img = tum_frame(KEYBOARD[0])
    again = create_embedder(offline.name)
    np.testing.assert_array_equal(offline.embed_images([img]), again.embed_images([img]))
    np.testing.assert_array_equal(offline.embed_texts(["a mug"]), again.embed_texts(["a mug"]))


def test_bad_inputs_raise_input_error(offline: Embedder) -> None:
    with pytest.raises(InputError, match="image 1"):
        offline.embed_images([np.zeros((8, 8, 3), np.uint8), np.zeros((8, 8), np.uint8)])
    with pytest.raises(InputError, match="uint8"):
        offline.embed_images([np.zeros((8, 8, 3), np.float32)])
    with pytest.raises(InputError, match="single string"):
        offline.embed_texts("a mug")  # type: ignore[arg-type]
    with pytest.raises(InputError, match="text 0"):
        offline.embed_texts([3])  # type: ignore[list-item]


def test_keyboard_query_ranks_keyboard_frames_first(offline: Embedder, tum_frame) -> None:
    vecs = offline.embed_images([tum_frame(n) for n in KEYBOARD + NO_KEYBOARD])
    sims = vecs @ offline.embed_texts(["a computer keyboard"])[0]
    assert sims[:3].min() > sims[3:].max(), sims


def test_game_controller_query_finds_the_small_gamepad(offline: Embedder, tum_frame, tum_labels) -> None:
    with_pad = ["1305031233.793747.jpg", "1305031238.861826.jpg", "1305031241.793694.jpg"]  # 128, 280, 368
    without = [*NO_KEYBOARD, "1305031232.193716.jpg", "1305031249.529692.jpg"]  # + 80, 600
    assert all("gamepad" in tum_labels[n] for n in with_pad) and all(
        "gamepad" not in tum_labels[n] for n in without
    )
    sims = (
        offline.embed_images([tum_frame(n) for n in with_pad + without])
        @ offline.embed_texts(["a game controller"])[0]
    )
    assert sims[:3].min() > sims[3:].max(), sims


def _small_scene(frame: np.ndarray, scale: float = 0.35) -> np.ndarray:
    """The frame shrunk into the top-left corner of a plain grey canvas: every object becomes small."""
    canvas = Image.new("RGB", (640, 480), (160, 160, 160))
    small = Image.fromarray(frame).resize((round(640 * scale), round(480 * scale)), Image.BILINEAR)
    canvas.paste(small, (20, 20))
    return np.asarray(canvas)


def test_tiles_find_a_small_keyboard(tum_frame) -> None:
    scenes = [_small_scene(tum_frame(n)) for n in [KEYBOARD[2], *NO_KEYBOARD[:2]]]
    margins = {}
    for tiles in (1, 5):
        e = create_embedder(f"offline:design=hybrid:tiles={tiles}:pool=fmax")
        sims = e.embed_images(scenes) @ e.embed_texts(["a computer keyboard"])[0]
        margins[tiles] = sims[0] - sims[1:].max()
    assert margins[5] > 0, margins  # with tiles the small keyboard scene ranks first
    assert margins[5] > margins[1] + 0.03, margins
