"""Fixtures: a small synthetic memory (real `ravenmem.Memory`, colour embedder), a scripted VLM,
and the `ravenmem` command run in a subprocess that can open that memory."""

from __future__ import annotations

import os
import subprocess
import sys
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

import ravenmem
from ravenmem.agent import VLMClient, VLMConfig
from ravenmem.types import Frame, Pose
from tests.agent.scripted_server import ScriptedModel
from tests.cli.helpers import ForkedCli
from tests.conftest import ColorEmbedder, solid

REPO = Path(__file__).resolve().parents[2]
T0 = 1_700_000_000.0
# (colour, x, y) per memory, 10 s apart: red at two places, blue seen three times
SCENE = [
    ("green", 0.0, 0.0),
    ("red", 1.0, 0.0),
    ("yellow", 2.0, 0.0),
    ("blue", 3.0, 1.0),
    ("white", 4.0, 1.0),
    ("cyan", 5.0, 2.0),
    ("blue", 6.0, 2.0),
    ("magenta", 7.0, 3.0),
    ("red", 8.0, 3.0),
    ("green", 9.0, 3.0),
    ("blue", 10.0, 4.0),
    ("black", 11.0, 4.0),
]
VLM_ENV = (
    "RAVENMEM_VLM_MODEL",
    "RAVENMEM_VLM_BASE_URL",
    "RAVENMEM_VLM_API_KEY",
    "RAVENMEM_CONFIG",
    "OPENAI_API_KEY",
)


def scene_frames() -> list[Frame]:
    return [
        Frame(image=solid(c), t=T0 + 10 * i, pose=Pose(x, y, 0.5, 0.1 * i), source="test", index=i)
        for i, (c, x, y) in enumerate(SCENE)
    ]


@pytest.fixture
def mem(tmp_path) -> Iterator[ravenmem.Memory]:
    m = ravenmem.create(tmp_path / "scene.mem", embedder=ColorEmbedder(), ocr=False, thumb_size=32)
    m.add_frames(scene_frames())
    yield m
    m.close()


@pytest.fixture
def server() -> Iterator[ScriptedModel]:
    with ScriptedModel() as srv:
        yield srv


def config_for(srv: ScriptedModel, **kw: object) -> VLMConfig:
    """Fast settings for tests: tiny backoff, short timeout."""
    base = dict(
        base_url=srv.base_url,
        model="scripted-vlm",
        api_key="test-key",
        timeout=2.0,
        max_retries=2,
        backoff=0.001,
        backoff_max=0.01,
    )
    base.update(kw)
    return VLMConfig(**base)  # type: ignore[arg-type]


@pytest.fixture
def client(server: ScriptedModel) -> VLMClient:
    return VLMClient(config_for(server))


# ---------------------------------------------------------------- the command, as users run it
@pytest.fixture
def color_plugin(tmp_path) -> Path:
    """A folder that, on PYTHONPATH, registers the test colour embedder by entry point, so that
    `ravenmem` in a subprocess can open a memory built with it."""
    site = tmp_path / "site"
    site.mkdir()
    (site / "ravenmem_test_color.py").write_text(
        "from tests.conftest import ColorEmbedder\n\ndef make(spec, **kw):\n    return ColorEmbedder()\n"
    )
    dist = site / "ravenmem_test_color-0.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: ravenmem-test-color\nVersion: 0\n")
    (dist / "entry_points.txt").write_text("[ravenmem.embedders]\ntest-color = ravenmem_test_color:make\n")
    return site


@pytest.fixture
def mem_path(tmp_path) -> Path:
    p = tmp_path / "lab.mem"
    with ravenmem.create(p, embedder=ColorEmbedder(), ocr=False, thumb_size=32) as m:
        m.add_frames(scene_frames())
    return p


def run_cli(
    *args: str, site: Path, home: Path, env: dict[str, str] | None = None, timeout: float = 120
) -> subprocess.CompletedProcess[str]:
    """`ravenmem ARGS` in a subprocess: no VLM settings inherited, config home at `home`."""
    base = {k: v for k, v in os.environ.items() if k not in VLM_ENV}
    base.update(PYTHONPATH=f"{REPO / 'src'}:{REPO}:{site}", XDG_CONFIG_HOME=str(home), COLUMNS="200")
    base.update(env or {})
    return subprocess.run(
        [sys.executable, "-m", "ravenmem.cli.main", *args],
        capture_output=True,
        text=True,
        env=base,
        timeout=timeout,
    )


@pytest.fixture
def forked_plugin_cli(color_plugin: Path, tmp_path: Path, forked_cli: ForkedCli) -> Callable[..., Any]:
    """`run_cli` above (the colour embedder's plugin site, no VLM settings, config home in the
    test's folder, COLUMNS=200), each command forked by the test process's driver (`ForkedCli`):
    for the many short refusals; `run_cli` stays the fresh-interpreter path."""
    env = {"XDG_CONFIG_HOME": str(tmp_path / "home"), "COLUMNS": "200"}
    return lambda *args: forked_cli(*args, env=env, unset=VLM_ENV, paths=(color_plugin,), timeout=120)
