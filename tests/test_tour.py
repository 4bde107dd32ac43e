"""The README's quick tour, run as written: its bash block line by line in a fresh folder laid out
as a clone (the shipped `examples/` and a `.venv/bin/activate` that puts this checkout's
`ravenmem` on PATH), then its Python block there."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest
from PIL import Image

REPO = Path(__file__).resolve().parents[1]


def tour_blocks() -> tuple[str, str]:
    """The bash and the Python code blocks of the README's "A quick tour" section."""
    readme = (REPO / "README.md").read_text(encoding="utf-8")
    section = readme.split("## A quick tour", 1)[1].split("\n## ", 1)[0]
    blocks = dict(reversed(re.findall(r"```(bash|python)\n(.*?)```", section, re.S)))
    return blocks["bash"], blocks["python"]


@pytest.fixture
def clone(tmp_path: Path) -> Path:
    """A folder where the tour's relative paths resolve as in a fresh clone: `examples/` (the
    shipped sample) and `.venv/bin/` with `ravenmem` and `python` of this checkout."""
    root = tmp_path / "ravenmem"
    root.mkdir()
    (root / "examples").symlink_to(REPO / "examples", target_is_directory=True)
    bin_ = root / ".venv" / "bin"
    bin_.mkdir(parents=True)
    path = os.pathsep.join([str(REPO / "src"), str(REPO)])
    for name, cmd in (
        ("ravenmem", f'"{sys.executable}" -m ravenmem.cli.main'),
        ("python", f'"{sys.executable}"'),
    ):
        (bin_ / name).write_text(f'#!/bin/sh\nPYTHONPATH="{path}" exec {cmd} "$@"\n')
        (bin_ / name).chmod(0o755)
    (bin_ / "activate").write_text(f'export PATH="{bin_}:$PATH"\n')
    return root


def test_the_readme_tour_runs_as_written(clone: Path) -> None:
    bash, python = tour_blocks()
    assert "ravenmem ingest examples/" in bash and "source .venv/bin/activate" in bash
    assert "../shared" not in bash  # nothing outside the clone
    env = {k: v for k, v in os.environ.items() if not k.startswith(("RAVENMEM_", "OPENAI_"))}
    env.update(XDG_CONFIG_HOME=str(clone / "config"), COLUMNS="160")
    r = subprocess.run(
        ["bash", "-euxo", "pipefail", "-c", bash],
        cwd=clone,
        env=env,
        capture_output=True,
        text=True,
        timeout=900,
    )
    assert r.returncode == 0, (r.stdout[-3000:], r.stderr[-3000:])
    assert "Traceback" not in r.stdout + r.stderr
    out = r.stdout
    assert "memory now holds" in out  # ingest
    assert out.count("text search:") >= 2 and "time search:" in out  # search, --time, --latest
    assert "type: position   method: offline   found" in out  # ask
    assert Image.open(clone / "hits.png").size[0] > 100  # --sheet
    assert (clone / "desk.mem").is_dir()

    py = subprocess.run(
        [str(clone / ".venv" / "bin" / "python"), "-c", python],
        cwd=clone,
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert py.returncode == 0, py.stderr[-3000:]
    rows = py.stdout.strip().splitlines()
    assert len(rows) == 5 and all("Pose(" in row for row in rows), py.stdout
