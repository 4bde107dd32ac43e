"""A goal the offline reasoner declines is explained: its best match's score under the
threshold, what the threshold is, the closest misses (the memories a search lists), and how to
go to one anyway; never a bare "not found" beside a search that lists the thing."""

from __future__ import annotations

import json
import re

import pytest
import typer
from typer.testing import CliRunner

import ravenmem
from ravenmem.agent import OfflineReasoner, OfflineReasonerConfig
from ravenmem.cli.nav import register
from ravenmem.demo import _declined


@pytest.fixture(scope="module")
def rooms(tmp_path_factory) -> str:
    """The synthetic rooms explored into a memory with a map (tests/box_embedder.py)."""
    app = typer.Typer()
    register(app)
    app.command("version")(lambda: None)  # a second command keeps typer in multi-command mode
    mem = tmp_path_factory.mktemp("rooms") / "rooms.mem"
    args = ["explore", "--env", "synthetic:rooms", "--memory", str(mem), "--steps", "500"]
    r = CliRunner().invoke(app, [*args, "--embedder", "test-boxes", "--keyframe-dist", "1.0", "--json"])
    assert r.exit_code == 0, r.output
    return str(mem)


def test_the_reasoner_says_why_it_declines_and_shows_what_a_search_finds(rooms: str) -> None:
    with ravenmem.open(rooms) as mem:
        # one word, so that the reasoner's queries are the search's (the boxes embedder reads
        # a text naming no colour as nothing any picture holds)
        top = mem.search_text("blue", k=3, diverse=False)
        # a threshold above every cosine: the search still lists blue memories first
        strict = OfflineReasoner(mem, config=OfflineReasonerConfig(min_score=2.0))
        ans = strict.ask("Where did you see blue?")
        assert not ans.found and ans.position is None and ans.position_source == "none"
        m = re.search(
            r"the best match, m(\d+) at .* scores ([\d.]+) \(([\d.]+) with its neighbours", ans.text
        )
        assert m and "under this memory's threshold 2.000 (the fixed min_score)" in ans.text, ans.text
        assert float(m[3]) < 2.0
        assert ans.notes == [f"declined: best support {float(m[3]):.3f} under the threshold 2.000"]
        # the closest misses are the evidence, best first: the search's own top hit among them
        assert len(ans.evidence) > 1 and ans.evidence[0].id == int(m[1])
        assert top[0].memory.id in {e.id for e in ans.evidence}
        # the calibrated threshold is explained as such
        miss = OfflineReasoner(mem).ask("Where did you see the purple elephant?")
        assert not miss.found and "things that are not there, such as a shark" in miss.text, miss.text
        thr = OfflineReasoner(mem).threshold("purple elephant")
        assert f"threshold {thr:.3f}" in miss.text
    # the demo's table cell for a declined text query says the same in short
    support = float(re.search(r"declined: best support ([\d.]+)", miss.notes[0])[1])
    assert _declined(miss.notes) == f"{support:.3f} < thr {thr:.3f}" and _declined([]) == "not found"


def test_navigate_names_the_reason_and_the_closest_misses(rooms: str) -> None:
    app = typer.Typer()
    register(app)
    app.command("version")(lambda: None)
    r = CliRunner().invoke(app, ["navigate", "--memory", rooms, "--to", "purple elephant"])
    assert r.exit_code == 1, r.output
    msg = r.stderr.strip()
    assert msg.startswith(
        "no path (the answer is the problem): 'purple elephant': not found in memory (offline): "
        "I don't remember seeing"
    ), msg
    assert "under this memory's threshold" in msg and "closest misses: m" in msg
    x, y = re.search(r"to go to one anyway: --to (-?[\d.]+),(-?[\d.]+)", msg).groups()
    assert "--method embedder-only" in msg and msg.endswith("the robot stays put")
    # the hint works as given
    r = CliRunner().invoke(app, ["navigate", "--memory", rooms, "--to", f"{x},{y}", "--json"])
    assert r.exit_code == 0, r.output
    assert json.loads(r.stdout)["ok"]
