"""What a person reads from the command: help pages (`-h` and `--help`, no `<bool>` placeholders,
text wrapped under its column), `info` in words (raw figures under `--json`), and the `search`
table's id column (the ids `--like ID` and `forget --ids` take)."""

from __future__ import annotations

import json
import math
import re
from typing import Any

import pytest
import typer

from ravenmem.cli.main import app, info_lines
from tests.cli.helpers import run_cli


def every_command() -> list[tuple[str, Any]]:
    """(path, command) for `ravenmem` and every command and subcommand under it (typer's own
    copy of click: groups are known by their `commands`)."""
    out: list[tuple[str, Any]] = []

    def walk(path: str, cmd: Any) -> None:
        out.append((path, cmd))
        for name, sub in getattr(cmd, "commands", {}).items():
            walk(f"{path} {name}", sub)

    walk("ravenmem", typer.main.get_command(app))
    return out


def help_of(path: str, cmd: Any) -> str:
    """The help page as `PATH --help` prints it 100 columns wide, with the root's settings."""
    root = typer.main.get_command(app)
    parent = root.context_class(root, info_name="ravenmem", terminal_width=100)
    if path != "ravenmem":
        parent = cmd.context_class(cmd, info_name=path.split()[-1], parent=parent, terminal_width=100)
    return cmd.get_help(parent)


def test_dash_h_is_help_everywhere() -> None:
    for args in ([], ["ingest"], ["eval", "study"]):
        short, long = run_cli(*args, "-h"), run_cli(*args, "--help")
        assert short.returncode == long.returncode == 0, short.stderr
        assert short.stdout == long.stdout and "Usage: ravenmem" in short.stdout
        assert "-h, --help" in short.stdout


def test_help_pages_have_no_bool_placeholders_and_wrap_under_their_column() -> None:
    commands = every_command()
    assert len(commands) > 20
    for path, cmd in commands:
        page = help_of(path, cmd)
        assert "<bool>" not in page and "│" not in page, path
        assert max(len(line) for line in page.splitlines()) <= 100, path
        col = None
        for line in page.splitlines():
            if not line.strip() or not line.startswith("  "):
                col = None  # a section heading or a blank line ends a block
                continue
            first = re.match(r"^  (\S.*?\S)  +(\S)", line)
            if first and not line.startswith("    "):
                col = first.start(2)  # an option's line: where its help text starts
            elif col is not None and line.startswith(" " * 4):
                indent = len(line) - len(line.lstrip())
                assert indent == col, (path, line)  # a continuation sits under the help text


def test_flags_are_shown_as_flags() -> None:
    page = help_of("ravenmem ingest", dict(every_command())["ravenmem ingest"])
    assert re.search(r"^  --ocr / --no-ocr  +read text", page, re.M)
    assert re.search(r"^  --wait  +wait while", page, re.M)


def test_info_prints_words_and_json_gives_the_figures(tum_desk) -> None:
    r = run_cli("info", "--memory", str(tum_desk.path))
    assert r.returncode == 0, r.stderr
    out = r.stdout
    for raw in ("True", "False", "{", "}", "'", "None", "_bytes", "t_min"):
        assert raw not in out, (raw, out)
    assert re.search(r"^ +memories  24 \(kept from 723 frames seen: 1 in 30\.1\)$", out, re.M), out
    assert re.search(r"^ +OCR  off$", out, re.M) and re.search(r"^ +thumbnails  320 px", out, re.M)
    assert re.search(
        r"^ +time  2011-05-10T12:40:29\.\d+Z to 2011-05-10T12:40:5\d\.\d+Z \(2\d\.\d s\)$", out, re.M
    )
    assert re.search(
        r"^ +ingest  tum:tum_fr1_rpy: 723 frames seen, 24 kept in \d+ s; skipped 696 keyframe selection",
        out,
        re.M,
    )
    data = json.loads(run_cli("info", "--memory", str(tum_desk.path), "--json").stdout)
    assert data["memories"] == 24 and data["ocr"] is False and data["ingests"][0]["kept"] == 24


def test_info_lines_put_unknown_keys_in_words() -> None:
    rows = dict(
        info_lines({"path": "m.mem", "memories": 0, "store": "local", "live": True, "map": {"id": "a1"}})
    )
    assert rows["live"] == "yes" and rows["map"] == "id: a1" and rows["memories"] == "0"


def test_info_lines_say_the_map_and_a_re_anchoring_in_words() -> None:
    base = {"path": "m.mem", "memories": 3, "store": "local", "frame_id": "map", "map_id": "lab"}
    rows = dict(info_lines(base | {"anchor": None}))
    assert rows["map"] == "lab (poses in frame map)" and "anchor" not in rows
    moved = {"transform": [1.0, -2.5, 0.0, math.pi / 2], "from": {"map_id": "memory:b.mem"}}
    rows = dict(info_lines(base | {"anchor": moved}))
    assert rows["anchor"] == "re-anchored from map memory:b.mem: moved (1.00, -2.50, 0.00) m, turned 90.0 deg"


def test_search_table_has_the_ids_like_takes(tum_desk) -> None:
    mem = str(tum_desk.path)
    table = run_cli("search", "a monitor", "--memory", mem, "-k", "3")
    hits = json.loads(run_cli("search", "a monitor", "--memory", mem, "-k", "3", "--json").stdout)["results"]
    assert table.returncode == 0, table.stderr
    header = next(line for line in table.stdout.splitlines() if "rank" in line)
    assert re.search(r"rank\W+id\W+score", header), header
    rows = [line for line in table.stdout.splitlines() if re.match(r"^│ +\d+ │", line)]
    ids = [int(line.split("│")[2]) for line in rows]
    assert ids == [h["id"] for h in hits]
    like = run_cli("search", "--like", str(ids[0]), "--memory", mem, "-k", "2", "--json")
    assert like.returncode == 0 and json.loads(like.stdout)["results"], like.stderr  # the id is taken


@pytest.mark.parametrize("bad", [["search", "-k"], ["ingest", "--nope"], ["-x"]])
def test_usage_errors_stay_one_line(bad: list[str]) -> None:
    r = run_cli(*bad)
    assert r.returncode == 2 and len(r.stderr.splitlines()) == 1 and r.stderr.startswith("error: "), r.stderr
    assert "--help" in r.stderr  # where to get help
