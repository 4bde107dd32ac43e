"""Running the real `ravenmem` command in a subprocess, and small memories to run it on."""

from __future__ import annotations

import json
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


class ForkedCli:
    """`run_cli` for many short command lines: `tests/hardening/forkrun.py` imports the command
    once and forks a process per command line (the real entry point, exit code and streams; the
    environment, plugin paths and folder given per call), ~0.1 s a command instead of ~1 s.
    For commands that refuse their input or read a little, where starting Python is the cost;
    `run_cli` stays the launcher of record (each behaviour keeps a test through it)."""

    def __init__(self) -> None:
        env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(REPO / "src"), str(REPO)]))
        self.proc = subprocess.Popen(
            [sys.executable, str(REPO / "tests" / "hardening" / "forkrun.py")],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            text=True,
            env=env,
        )

    def __call__(
        self,
        *args: str,
        env: dict[str, str] | None = None,
        cwd: Path | None = None,
        timeout: float = 300,
        unset: tuple[str, ...] = (),
        paths: tuple[Path, ...] = (),
    ) -> subprocess.CompletedProcess[str]:
        """As `run_cli(*args, env=, cwd=, timeout=, unset=, paths=)`."""
        full = {k: v for k, v in os.environ.items() if k not in unset}
        full["PYTHONPATH"] = os.pathsep.join([str(REPO / "src"), str(REPO), *map(str, paths)])
        full.update(env or {})
        req = {"argv": list(args), "timeout": timeout, "env": full, "paths": [str(p) for p in paths]}
        if cwd is not None:
            req["cwd"] = str(cwd)
        assert self.proc.stdin is not None and self.proc.stdout is not None
        self.proc.stdin.write(json.dumps(req) + "\n")
        self.proc.stdin.flush()
        line = self.proc.stdout.readline()
        if not line:
            raise RuntimeError("the command driver (tests/hardening/forkrun.py) died")
        r = json.loads(line)
        return subprocess.CompletedProcess(
            [sys.executable, "-m", "ravenmem.cli.main", *args], r["rc"], r["stdout"], r["stderr"]
        )

    def close(self) -> None:
        if self.proc.stdin is not None:
            self.proc.stdin.close()
        self.proc.wait(30)


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
