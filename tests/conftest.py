"""Shared test fixtures: a tiny deterministic embedder, the real TUM data and one memory of it.

The TUM RGB-D recording (freiburg1_rpy) is read from $RAVENMEM_TUM_DATA, by default the
workplace's `../shared/data/tum_fr1_rpy` beside the checkout. Tests that need it skip with the
reason when it is absent, and fail instead when RAVENMEM_REQUIRE_DATA=1 (as `.ci/run` sets it),
so that a CI run without the data cannot pass by skipping them.
"""

from __future__ import annotations

import fcntl
import json
import os
import subprocess
import sys
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pytest

if TYPE_CHECKING:
    from tests.cli.helpers import ForkedCli

REPO = Path(__file__).resolve().parents[1]
TUM = Path(os.environ.get("RAVENMEM_TUM_DATA") or REPO.parent / "shared" / "data" / "tum_fr1_rpy")

COLORS = {
    "red": (255, 0, 0),
    "green": (0, 255, 0),
    "blue": (0, 0, 255),
    "yellow": (255, 255, 0),
    "cyan": (0, 255, 255),
    "magenta": (255, 0, 255),
    "white": (255, 255, 255),
    "black": (0, 0, 0),
}


class ColorEmbedder:
    """Images -> their mean colour direction; texts -> the colour they name.

    Cheap and exact, so facade tests can check ranking, filters and fusion without a model.
    """

    name = "test-color"
    dim = 4

    def embed_images(self, images: Sequence[np.ndarray]) -> np.ndarray:
        out = []
        for im in images:
            m = im.reshape(-1, 3).astype(np.float32).mean(0) / 255.0
            out.append([m[0], m[1], m[2], 0.15])
        v = np.asarray(out, dtype=np.float32)
        return v / np.linalg.norm(v, axis=1, keepdims=True)

    def embed_texts(self, texts: Sequence[str]) -> np.ndarray:
        out = []
        for t in texts:
            c = next((COLORS[w] for w in t.lower().split() if w in COLORS), (0, 0, 0))
            out.append([c[0] / 255, c[1] / 255, c[2] / 255, 0.15])
        v = np.asarray(out, dtype=np.float32)
        return v / np.linalg.norm(v, axis=1, keepdims=True)


def solid(color: str, h: int = 48, w: int = 64) -> np.ndarray:
    img = np.zeros((h, w, 3), dtype=np.uint8)
    img[:] = COLORS[color]
    return img


def pytest_configure(config: pytest.Config) -> None:
    """Bring the checkout's bytecode up to date once per run (each xdist worker: a no-op when
    current). The tests start hundreds of `ravenmem` processes; under PYTHONDONTWRITEBYTECODE=1
    (set on some machines) none of them writes its `__pycache__`, so after any edit each one
    compiled the changed modules again (0.2-0.3 s CPU a process). Same sources, same behaviour:
    Python checks every .pyc against its source's mtime."""
    if os.environ.get("PYTHONDONTWRITEBYTECODE"):
        import compileall

        compileall.compile_dir(REPO / "src", quiet=2)


@pytest.fixture
def color_embedder() -> ColorEmbedder:
    return ColorEmbedder()


def tum_data() -> Path:
    """The TUM recording's folder; skips the calling test when it is absent (fails instead
    under RAVENMEM_REQUIRE_DATA=1)."""
    if not (TUM / "rgb.txt").is_file():
        reason = (
            f"real TUM data not found at {TUM} (set RAVENMEM_TUM_DATA to a freiburg1_rpy folder; "
            "the default is the workplace's ../shared/data/tum_fr1_rpy)"
        )
        if os.environ.get("RAVENMEM_REQUIRE_DATA") == "1":
            pytest.fail(f"RAVENMEM_REQUIRE_DATA=1 but {reason}", pytrace=False)
        pytest.skip(reason)
    return TUM


@pytest.fixture
def tum_path() -> Path:
    return tum_data()


@dataclass(frozen=True)
class TumDesk:
    """A memory of every 30th TUM frame (24 memories; offline embedder, no OCR, thumbnails),
    built once per run by `ravenmem ingest` as a user runs it (once for all pytest-xdist
    workers), and the ingest's JSON report.
    Shared: tests open it to read; a test that writes copies it first (shutil.copytree)."""

    path: Path
    report: dict


@pytest.fixture(scope="session")
def tum_desk(tmp_path_factory: pytest.TempPathFactory) -> TumDesk:
    data = tum_data()
    root = tmp_path_factory.getbasetemp()
    if os.environ.get("PYTEST_XDIST_WORKER"):  # parallel workers of one run build it once, together
        root = root.parent
    folder = root / "tum-desk"
    folder.mkdir(exist_ok=True)
    with open(folder / "build.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # the other workers wait for the first one's build
        report = folder / "report.json"
        if not report.is_file():
            path = folder / "desk.mem"
            env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(REPO / "src"), str(REPO)])}
            args = ["ingest", str(data), "--format", "tum", "--memory", str(path), "--stride", "30"]
            r = subprocess.run(
                [sys.executable, "-m", "ravenmem.cli.main", *args, "--no-ocr", "--json"],
                capture_output=True,
                text=True,
                env=env,
                timeout=600,
            )
            assert r.returncode == 0, r.stderr[-2000:]
            report.write_text(r.stdout)
    return TumDesk(folder / "desk.mem", json.loads(report.read_text()))


@pytest.fixture(scope="session")
def forked_cli() -> Iterator[ForkedCli]:
    """`tests.cli.helpers.ForkedCli`: one command driver per test process, for many short
    `ravenmem` command lines (a forked process each, ~0.1 s instead of ~1 s)."""
    from tests.cli.helpers import ForkedCli

    driver = ForkedCli()
    yield driver
    driver.close()
