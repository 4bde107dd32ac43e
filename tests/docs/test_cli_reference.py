"""docs/cli.md, the command reference, is the command tree's own help: the committed page is
what `scripts/gen_cli_docs.py` makes from the current CLI, and every command and option is in it."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import typer

from ravenmem.cli.main import app
from ravenmem.cli.reference import sections

REPO = Path(__file__).resolve().parents[2]
SCRIPT = REPO / "scripts" / "gen_cli_docs.py"


def gen(*args: str) -> subprocess.CompletedProcess[str]:
    env = {k: v for k, v in os.environ.items() if not k.startswith("RAVENMEM_")}
    env["PYTHONPATH"] = os.pathsep.join([str(REPO / "src"), str(REPO)])
    return subprocess.run(
        [sys.executable, str(SCRIPT), *args], capture_output=True, text=True, env=env, timeout=120
    )


def test_the_committed_page_is_current() -> None:
    r = gen("--check")
    assert r.returncode == 0, r.stderr or "docs/cli.md is out of date: run python scripts/gen_cli_docs.py"


def test_a_stale_page_is_caught_and_rewritten(tmp_path: Path) -> None:
    page = tmp_path / "cli.md"
    page.write_text(
        (REPO / "docs" / "cli.md").read_text().replace("| `-k, --k` | `<int>` | `5` |", "| `-k` |")
    )
    r = gen("--check", "--page", str(page))
    assert r.returncode == 1 and "is out of date" in r.stderr
    assert gen("--page", str(page)).returncode == 0
    assert page.read_text() == (REPO / "docs" / "cli.md").read_text()


def test_every_command_and_option_has_its_row() -> None:
    page = (REPO / "docs" / "cli.md").read_text()
    secs = {s.path: s for s in sections(app)}
    group = typer.main.get_command(app)
    assert {"ravenmem ingest", "ravenmem ask", "ravenmem ros run", "ravenmem eval study top-k"} <= set(secs)
    assert set(secs) >= {f"ravenmem {n}" for n, c in group.commands.items() if not c.hidden}  # type: ignore[attr-defined]
    for path, sec in secs.items():
        body = page.split(f"\n## {path}\n", 1)[1].split("\n## ", 1)[0]
        assert sec.usage in body
        cmd = group
        for name in path.split()[1:]:
            cmd = cmd.commands[name]  # type: ignore[attr-defined]
        cells = [c.split(" / ") for c in re.findall(r"^\| `([^`]*)` \|", body, re.M)]
        names = {n.strip() for cell in cells for part in cell for n in part.split(", ")}
        for param in cmd.params:
            if "--help" in param.opts:
                continue
            if param.param_type_name == "argument":
                assert (param.metavar or param.name or "").strip("[]").upper() in {
                    n.upper() for n in names
                }, (
                    path,
                    param.name,
                )
            else:
                assert set(param.opts) | set(param.secondary_opts) <= names, (path, param.opts)
    search = page.split("\n## ravenmem search\n", 1)[1].split("\n## ", 1)[0]
    assert "| `-k, --k` | `<int>` | `5` | how many results |" in search
    assert "| `--diverse / --no-diverse` | flag | `diverse` |" in search
    assert (
        "| `-m, --memory` | `<Path>` | required | memory folder |" in page.split("\n## ravenmem ingest\n")[1]
    )
