"""The `ravenmem` command's plumbing as a user meets it: exit codes, one-line errors, no
tracebacks, text printed literally (never as rich markup), nonsense refused (subprocesses)."""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest

import ravenmem
from tests.agent.scripted_server import ScriptedModel, error
from tests.cli.helpers import T0, assert_one_line_error, huge_png, make_memory, run_cli


@pytest.fixture(scope="module")
def mem(tmp_path_factory) -> Path:
    return make_memory(tmp_path_factory.mktemp("trust") / "m.mem")


def test_version():
    r = run_cli("--version")
    assert r.returncode == 0 and r.stdout.strip() == f"ravenmem {ravenmem.__version__}" and not r.stderr


@pytest.mark.parametrize(
    "args,needle",
    [
        (["search", "x", "--bogus", "-m", "MEM"], "No such option: --bogus"),
        (["search", "x"], "Missing option '--memory'"),
        (["frobnicate", "--memory", "MEM"], "No such command 'frobnicate'"),
        (["search", "x", "-m", "MEM", "-k", "five"], "Invalid value for '-k'"),
        (["info"], "Missing option '--memory'"),
    ],
)
def test_usage_errors_are_one_line_exit_2(mem: Path, args: list[str], needle: str):
    line = assert_one_line_error(run_cli(*[str(mem) if a == "MEM" else a for a in args]))
    assert needle in line and "--help" in line


def test_bare_command_prints_help():
    r = run_cli()
    assert "Usage: ravenmem" in r.stdout + r.stderr and "Traceback" not in r.stderr


def test_a_failed_ask_exits_1(mem: Path, tmp_path: Path):
    env = {"XDG_CONFIG_HOME": str(tmp_path), "RAVENMEM_VLM_API_KEY": "k"}
    env.update({v: "" for v in ("RAVENMEM_VLM_MODEL", "RAVENMEM_CONFIG")})
    with ScriptedModel(default=error(503, "overloaded")) as srv:
        r = run_cli(
            "ask",
            "Where is the red box?",
            "-m",
            str(mem),
            "--base-url",
            srv.base_url,
            "--model",
            "vlm",
            "--max-retries",
            "0",
            env=env,
        )
    assert r.returncode == 1, (r.stdout, r.stderr)
    assert "FAILED" in r.stdout and "Traceback" not in r.stderr + r.stdout


def test_user_text_is_printed_literally_not_as_markup(mem: Path, tmp_path: Path):
    # a closing tag crashed rich (MarkupError); brackets that look like tags vanished
    line = assert_one_line_error(run_cli("search", "--time", "[/bold] x", "-m", str(mem)))
    assert "'[/bold] x'" in line
    line = assert_one_line_error(run_cli("search", "x", "-m", str(tmp_path / "[nan, nan, 1.0]" / "m.mem")))
    assert "[nan, nan, 1.0]" in line and "does not exist" in line
    # table cells and info values: a memory folder whose name looks like markup
    odd = make_memory(tmp_path / "[red]room.mem", n=2)
    r = run_cli("search", "--time", "0", "-m", str(odd), cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert "[red]room.mem/thumbs/" in r.stdout
    r = run_cli("info", "-m", str(odd))
    assert r.returncode == 0 and f"path: {odd}" in r.stdout


@pytest.mark.parametrize(
    "args,needle",
    [
        (["--time", "1e400"], "'1e400' is not a finite time"),
        (["--time", "nan"], "'nan' is not a finite time"),
        (["--time", "0", "--after", "nan"], "'nan' is not a finite time"),
        (["--time", "0", "--before", "-inf"], "'-inf' is not a finite time"),
        (["--time", "start+inf"], "not a finite"),
        (["a red box", "--near", "nan,2,5"], "--near"),
        (["a red box", "--near", "1,2,inf"], "--near"),
        (["--position", "nan,1"], "x"),
        (["--position", "1,2", "--radius", "inf"], "radius"),
        (["--time", "0", "-k", "0"], "--k: expected a whole number from 1 to 1000"),
        (["--time", "0", "-k", "-1"], "--k: expected a whole number from 1 to 1000"),
        (["--time", "0", "-k", str(2**63)], "k"),
        (["--time", "0", "--near", "1,2,3"], "--near applies to text and image searches only"),
    ],
)
def test_nonsense_numbers_are_refused(mem: Path, args: list[str], needle: str):
    line = assert_one_line_error(run_cli("search", *args, "-m", str(mem)))
    assert needle in line


def test_query_with_an_invalid_utf8_byte(mem: Path):
    line = assert_one_line_error(run_cli("search", os.fsdecode(b"caf\xff"), "-m", str(mem)))
    assert "query" in line and ("UTF-8" in line or "unicode" in line)


def test_image_files_that_cannot_be_decoded(mem: Path, tmp_path: Path):
    line = assert_one_line_error(
        run_cli("search", "--image", str(huge_png(tmp_path / "bomb.png")), "-m", str(mem))
    )
    assert "bomb.png" in line and "too large" in line
    (tmp_path / "notes.jpg").write_text("not a picture")
    line = assert_one_line_error(run_cli("search", "--image", str(tmp_path / "notes.jpg"), "-m", str(mem)))
    assert "notes.jpg" in line and "cannot be read" in line
    truncated = tmp_path / "cut.png"
    truncated.write_bytes(huge_png(tmp_path / "small.png", 64, 48).read_bytes()[:40])
    line = assert_one_line_error(run_cli("search", "--image", str(truncated), "-m", str(mem)))
    assert "cut.png" in line
    line = assert_one_line_error(run_cli("search", "--image", str(tmp_path), "-m", str(mem)))
    assert "not a file" in line


def test_info_prints_the_spatial_extent(mem: Path):
    r = run_cli("info", "-m", str(mem))
    assert r.returncode == 0, r.stderr
    assert "extent: x 0.00 .. 4.00 m, y 0.00 .. 8.00 m, z 0.50 .. 0.50 m" in r.stdout
    data = json.loads(run_cli("info", "-m", str(mem), "--json").stdout)
    assert data["extent"] == {"x": [0.0, 4.0], "y": [0.0, 8.0], "z": [0.5, 0.5]}
    assert data["t_min"] == T0 and data["store"] == "local"
