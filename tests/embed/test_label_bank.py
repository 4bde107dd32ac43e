"""The label bank cache: built offline, written atomically, rebuilt when corrupt or stale."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from ravenmem.embed._text import MiniLM, build_label_bank, cache_dir, class_phrases, load_label_bank

NAMES = ["computer keyboard, keypad", "coffee mug", "joystick"]


@pytest.fixture(scope="module")
def minilm() -> MiniLM:
    return MiniLM()


def test_phrases_cover_every_synonym() -> None:
    ps = class_phrases("computer keyboard, keypad", ("{}", "a photo of a {}."))
    assert ps == ["computer keyboard", "a photo of a computer keyboard.", "keypad", "a photo of a keypad."]


def test_cache_is_written_reused_and_rebuilt_when_corrupt(
    minilm: MiniLM, tmp_path: Path, monkeypatch
) -> None:
    monkeypatch.setenv("RAVENMEM_CACHE_DIR", str(tmp_path / "cache"))
    assert cache_dir() == tmp_path / "cache"
    bank = load_label_bank(minilm, NAMES)
    assert bank.shape == (3, 384) and bank.dtype == np.float32
    np.testing.assert_allclose(np.linalg.norm(bank, axis=1), 1.0, atol=1e-5)
    files = list((tmp_path / "cache").glob("label-bank-*.npy"))
    assert len(files) == 1 and not list((tmp_path / "cache").glob("*.tmp"))
    np.testing.assert_array_equal(np.load(files[0]), bank)

    files[0].write_bytes(b"not a numpy file")  # a crash or a bad disk must not break the embedder
    again = load_label_bank(minilm, NAMES)
    np.testing.assert_allclose(again, bank, atol=1e-6)
    np.testing.assert_allclose(np.load(files[0]), bank, atol=1e-6)

    other = load_label_bank(minilm, NAMES[:2])  # other names: another cache entry, not a stale hit
    assert other.shape == (2, 384)
    assert len(list((tmp_path / "cache").glob("label-bank-*.npy"))) == 2


def test_bank_is_semantic(minilm: MiniLM) -> None:
    bank = build_label_bank(minilm, NAMES)
    q = minilm.encode(["a game controller", "a cup of coffee"])
    assert int(np.argmax(q[0] @ bank.T)) == 2
    assert int(np.argmax(q[1] @ bank.T)) == 1


def test_unwritable_cache_still_works(minilm: MiniLM, tmp_path: Path, monkeypatch) -> None:
    blocker = tmp_path / "file"
    blocker.write_text("x")
    monkeypatch.setenv("RAVENMEM_CACHE_DIR", str(blocker / "sub"))  # cannot mkdir under a file
    assert load_label_bank(minilm, NAMES[:1]).shape == (1, 384)
