import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))

from colour_embedder import ColourEmbedder  # noqa: E402

from ravenmem.embed.base import EMBEDDERS  # noqa: E402


@EMBEDDERS.register("test-colour")
def _colour(spec: str = "", **_: object) -> ColourEmbedder:
    return ColourEmbedder()


@pytest.fixture
def colour_embedder() -> ColourEmbedder:
    return ColourEmbedder()
