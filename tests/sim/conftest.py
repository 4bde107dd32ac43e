import pytest

from tests.box_embedder import BoxEmbedder  # registers `test-boxes`


@pytest.fixture
def box_embedder() -> BoxEmbedder:
    return BoxEmbedder()
