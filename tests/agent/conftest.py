"""Fixtures: a small synthetic memory (real `ravenmem.Memory`, colour embedder) and a scripted VLM."""

from __future__ import annotations

from collections.abc import Iterator

import pytest

import ravenmem
from ravenmem.agent import VLMClient, VLMConfig
from ravenmem.types import Frame, Pose
from tests.agent.scripted_server import ScriptedModel
from tests.conftest import ColorEmbedder, solid

T0 = 1_700_000_000.0
# (colour, x, y) per memory, 10 s apart: red at two places, blue seen three times
SCENE = [
    ("green", 0.0, 0.0), ("red", 1.0, 0.0), ("yellow", 2.0, 0.0), ("blue", 3.0, 1.0), ("white", 4.0, 1.0),
    ("cyan", 5.0, 2.0), ("blue", 6.0, 2.0), ("magenta", 7.0, 3.0), ("red", 8.0, 3.0), ("green", 9.0, 3.0),
    ("blue", 10.0, 4.0), ("black", 11.0, 4.0),
]  # fmt: skip


@pytest.fixture
def mem(tmp_path) -> Iterator[ravenmem.Memory]:
    m = ravenmem.create(tmp_path / "scene.mem", embedder=ColorEmbedder(), ocr=False, thumb_size=32)
    m.add_frames([
        Frame(image=solid(c), t=T0 + 10 * i, pose=Pose(x, y, 0.5, 0.1 * i), source="test", index=i)
        for i, (c, x, y) in enumerate(SCENE)
    ])  # fmt: skip
    yield m
    m.close()


@pytest.fixture
def server() -> Iterator[ScriptedModel]:
    with ScriptedModel() as srv:
        yield srv


def config_for(srv: ScriptedModel, **kw: object) -> VLMConfig:
    """Fast settings for tests: tiny backoff, short timeout."""
    base = dict(base_url=srv.base_url, model="scripted-vlm", api_key="test-key", timeout=2.0, max_retries=2,
                backoff=0.001, backoff_max=0.01)  # fmt: skip
    base.update(kw)
    return VLMConfig(**base)  # type: ignore[arg-type]


@pytest.fixture
def client(server: ScriptedModel) -> VLMClient:
    return VLMClient(config_for(server))
