"""An empty value is not a value: `-m ''` would be the current folder, `--keyframes ''` the
default rules and `--map-id ''` no map; each is refused in one line, and nothing is written."""

from __future__ import annotations

import pytest

from tests.cli.helpers import REPO, assert_one_line_error, run_cli

SAMPLE = str(REPO / "examples" / "tum_desk")


@pytest.mark.parametrize(
    ("args", "words"),
    [
        (("ingest", SAMPLE, "-m", ""), "--memory' / '-m': must not be empty"),
        (("ingest", SAMPLE, "-m", "{tmp}/m.mem", "--keyframes", ""), "--keyframes: must not be empty"),
        (("ingest", SAMPLE, "-m", "{tmp}/m.mem", "--map-id", " "), "--map-id: must not be empty"),
        (("info", "-m", ""), "--memory' / '-m': must not be empty"),
        (("search", "red", "-m", ""), "--memory' / '-m': must not be empty"),
        (("ros", "run", "-m", ""), "--memory' / '-m': must not be empty"),
    ],
)
def test_empty_values_are_refused(tmp_path, args, words):
    r = run_cli(*(a.format(tmp=tmp_path) for a in args), cwd=tmp_path)
    line = assert_one_line_error(r)
    assert words in line, line
    assert sorted(p.name for p in tmp_path.iterdir()) == []  # nothing written, here or in the cwd
