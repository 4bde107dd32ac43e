"""A small memory of distinct pictures, and the `ravenmem` command (colour embedder registered)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np

import ravenmem
from ravenmem.types import Frame, Pose
from tests.conftest import COLORS, ColorEmbedder

REPO = Path(__file__).resolve().parents[2]
T0 = 1_700_000_000.0
NAMES = ["red", "green", "blue", "yellow", "cyan", "magenta", "white"]


def picture(i: int, h: int = 48, w: int = 64) -> np.ndarray:
    """Memory i's picture: its colour, with a dark stripe at a place of its own (so two
    pictures of one colour still differ)."""
    img = np.zeros((h, w, 3), np.uint8)
    img[:] = COLORS[NAMES[i % len(NAMES)]]
    x = 4 + 7 * i % (w - 12)
    img[:, x : x + 8] = (30, 30, 30)
    img[h // 2 :, : w // 3] = (128, 64, 0)
    return img


def make_memory(path: Path, n: int = 7) -> Path:
    """n memories along a line: memory i at (i, 0.5 i, 0.1), yaw 0.2 i, t = T0 + 10 i."""
    with ravenmem.create(path, embedder=ColorEmbedder(), ocr=False, thumb_size=64) as m:
        m.add_frames(
            [
                Frame(image=picture(i), t=T0 + 10 * i, pose=Pose(float(i), 0.5 * i, 0.1, 0.2 * i), index=i)
                for i in range(n)
            ]
        )
    return path


def cli(*args: str, cwd: Path | None = None) -> subprocess.CompletedProcess[str]:
    """The real command in a subprocess, with this checkout's sources and the colour embedder
    registered by name (tests/server/serve_color.py)."""
    env = dict(os.environ, PYTHONPATH=str(REPO / "src"))
    return subprocess.run(
        [sys.executable, str(REPO / "tests" / "server" / "serve_color.py"), *args],
        capture_output=True,
        text=True,
        env=env,
        cwd=cwd,
        timeout=300,
    )


def cli_json(*args: str) -> Any:
    r = cli(*args, "--json")
    assert r.returncode == 0, r.stderr[-3000:]
    return json.loads(r.stdout)
