"""`ravenmem search` says when nothing supports a query, by the rule `ask --offline` declines by
(ravenmem.agent.support), on the desk sample the README's tour uses (examples/tum_desk)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from tests.cli.helpers import REPO, run_cli


@pytest.fixture(scope="module")
def desk(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("support") / "desk.mem"
    r = run_cli("ingest", str(REPO / "examples" / "tum_desk"), "--memory", str(path), "--no-ocr")
    assert r.returncode == 0, r.stderr[-2000:]
    return path


def search(desk: Path, query: str, *extra: str) -> tuple[str, list[dict]]:
    shown = run_cli("search", query, "--memory", str(desk), "-k", "5", *extra)
    data = run_cli("search", query, "--memory", str(desk), "-k", "5", "--json", *extra)
    assert shown.returncode == 0 and data.returncode == 0, shown.stderr[-2000:] + data.stderr[-2000:]
    return shown.stdout, json.loads(data.stdout)["results"]


def test_a_thing_not_on_the_desk_is_said_to_be_unsupported(desk: Path) -> None:
    shown, rows = search(desk, "a potted plant")
    assert len(rows) == 5 and [r["supported"] for r in rows] == [False] * 5  # hits, none supported
    warning = " ".join(shown.split())
    assert 'warning: nothing in this memory supports "a potted plant"' in warning
    # ask declines the same thing by the same rule
    r = run_cli("ask", "where did I see a potted plant?", "--memory", str(desk), "--offline", "--json")
    assert r.returncode == 0 and json.loads(r.stdout)["found"] is False, r.stderr[-2000:]


def test_a_keyboard_on_the_desk_is_supported(desk: Path) -> None:
    shown, rows = search(desk, "a computer keyboard")
    assert rows[0]["supported"] is True and "nothing in this memory supports" not in shown
    # the time tool is not judged: no verdict, no warning
    r = run_cli("search", "--time", "+5s", "-k", "3", "--memory", str(desk), "--json")
    assert r.returncode == 0 and [row["supported"] for row in json.loads(r.stdout)["results"]] == [None] * 3


def test_ask_shows_image_paths_relative_as_search_does(desk: Path) -> None:
    """Run from the memory's folder: both name the pictures `desk.mem/thumbs/...`, not by the
    absolute path (a table column of 120 characters)."""
    for args in (
        ("ask", "where did I see the game controller?", "--offline"),
        ("search", "a game controller"),
    ):
        r = run_cli(*args, "--memory", "desk.mem", cwd=desk.parent, env={"COLUMNS": "250"})
        assert r.returncode == 0, r.stderr[-2000:]
        assert "desk.mem/thumbs/" in r.stdout and str(desk.parent) not in r.stdout, r.stdout
