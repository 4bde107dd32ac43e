"""Running the real `ravenmem` command in a subprocess, and small memories to run it on."""

from __future__ import annotations

import os
import struct
import subprocess
import sys
import zlib
from pathlib import Path

import ravenmem
from ravenmem.types import Frame, Pose
from tests.conftest import ColorEmbedder, solid

REPO = Path(__file__).resolve().parents[2]
T0 = 1_700_000_000.0
COLOURS = ["red", "green", "blue", "yellow", "white"]


def run_cli(
    *args: str,
    env: dict[str, str] | None = None,
    cwd: Path | None = None,
    timeout: float = 300,
    unset: tuple[str, ...] = (),
    paths: tuple[Path, ...] = (),
    python_flags: tuple[str, ...] = (),
) -> subprocess.CompletedProcess[str]:
    """`python -m ravenmem.cli.main ARGS` with this checkout's sources; real exit code and streams.

    The one launcher of the tests: `env` adds variables, `unset` removes inherited ones (e.g. a
    RAVENMEM_SERVER of the developer's shell), `paths` go on PYTHONPATH after the checkout (a
    plugin site), `python_flags` go to the interpreter (e.g. `-X importtime`)."""
    full = {k: v for k, v in os.environ.items() if k not in unset}
    full["PYTHONPATH"] = os.pathsep.join([str(REPO / "src"), str(REPO), *map(str, paths)])
    full.update(env or {})
    return subprocess.run(
        [sys.executable, *python_flags, "-m", "ravenmem.cli.main", *args],
        capture_output=True,
        text=True,
        errors="backslashreplace",
        cwd=cwd,
        env=full,
        timeout=timeout,
    )


def assert_one_line_error(r: subprocess.CompletedProcess[str], code: int = 2, warnings: bool = False) -> str:
    """Exit `code`, exactly one line on stderr starting with `error:`, no traceback; the line.

    `warnings=True` lets `warning: ` lines stand before it (a command that warned, then failed)."""
    lines = [ln for ln in r.stderr.splitlines() if not (warnings and ln.startswith("warning: "))]
    assert r.returncode == code, (r.returncode, r.stdout[-2000:], r.stderr[-2000:])
    assert "Traceback" not in r.stderr and "Traceback" not in r.stdout, r.stderr[-2000:]
    assert len(lines) == 1 and lines[0].startswith("error: "), r.stderr[-2000:]
    return lines[0]


def make_memory(path: Path, n: int = 5, thumb_size: int = 32) -> Path:
    """A small memory on disk (colour embedder: time and position searches need no model)."""
    with ravenmem.create(path, embedder=ColorEmbedder(), ocr=False, thumb_size=thumb_size) as m:
        m.add_frames(
            [
                Frame(image=solid(COLOURS[i % 5]), t=T0 + 10 * i, pose=Pose(float(i), 2.0 * i, 0.5), index=i)
                for i in range(n)
            ]
        )
    return path


def huge_png(path: Path, width: int = 20000, height: int = 20000) -> Path:
    """A tiny PNG file whose header claims width x height pixels (a decompression bomb)."""

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    ihdr = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    body = chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(b"\x00" * 64)) + chunk(b"IEND", b"")
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + body)
    return path
