"""Shared fixtures: the real TUM frames and one offline embedder per session (loading is ~2 s)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from tests.conftest import TUM, tum_data

REPO = Path(__file__).resolve().parents[2]
LABELS = REPO / "benchmarks" / "data" / "tum_labels.json"


@pytest.fixture(scope="session")
def tum_labels() -> dict[str, list[str]]:
    tum_data()
    return json.loads(LABELS.read_text())["frames"]


@pytest.fixture(scope="session")
def tum_frame():
    """Load a TUM frame (RGB uint8) by file name."""

    def load(name: str) -> np.ndarray:
        path = TUM / "rgb" / name
        if not path.is_file():
            pytest.skip(f"TUM frame {path} not found")
        return np.asarray(Image.open(path).convert("RGB"))

    return load


@pytest.fixture(scope="session")
def offline():
    """The default offline embedder, loaded once for the whole session."""
    from ravenmem.embed import create_embedder

    emb = create_embedder("offline")
    emb.embed_texts(["warm-up"])  # loads both models and the label bank
    return emb
