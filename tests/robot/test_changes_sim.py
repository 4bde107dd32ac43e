"""A world that changes, in simulation: the robot explores the two-room world, the red box is
moved to the other room and the green box taken away, and the robot explores again into the
same memory a day later. The memory, its tools, the explorer, the offline reasoner and the
VLM agent (a scripted model over real HTTP) are the real ones; the embedder really looks at
the pictures (the share of red, green and blue pixels). Ground truth (which boxes each
keyframe showed, and what a view would have shown had the box stayed) comes from the
simulator."""

from __future__ import annotations

import json
import math
import re
from typing import Any

from ravenmem.agent import Agent, VLMConfig
from ravenmem.agent.offline import OfflineReasoner
from ravenmem.memory.places import ChangeHit
from ravenmem.timeparse import fmt_time
from ravenmem.tools import TOOLS
from tests.agent.scripted_server import ScriptedModel, answer, tool
from tests.cli.helpers import assert_one_line_error, run_cli
from tests.robot.changes_world import GREEN, RED, A, B, World


def _dist(rec: Any, xy: tuple[float, float]) -> float:
    return math.hypot(rec.pose.x - xy[0], rec.pose.y - xy[1])


def test_latest_mode_says_where_the_moved_box_is_now(world: World) -> None:
    w = world.mem.last_seen("red box")
    assert w.status in ("still there", "not revisited") and w.now is w.places[0]
    now = w.now.last
    assert now.t >= world.day2_start and world.showed(now.id, RED)  # a day-2 view that shows it
    assert _dist(now, B) < 4.0 < _dist(now, A)
    # the ordinary text tool ranks the many day-1 views of place A first; the latest mode does not
    best = TOOLS["search_text"].run(world.mem, {"query": "red box"}, k=1)[0].memory
    latest = TOOLS["search_text"].run(world.mem, {"query": "red box", "latest": True}, k=3)
    assert isinstance(latest[0], ChangeHit) and latest[0].memory.id == now.id != best.id
    assert best.t < world.day2_start


def test_the_old_place_was_looked_at_again_without_it(world: World) -> None:
    w = world.mem.last_seen("red box")
    old = [p for p in w.places if p.last.t < world.day2_start]
    assert old and all(p.verdict == "moved" for p in old)
    p = max(old, key=lambda p: len(p.sightings))
    assert _dist(p.best.memory, A) < 3.0 and all(world.showed(h.memory.id, RED) for h in p.sightings)
    assert p.moved_to == 1 and p.seen_since is not None and p.seen_since.memory.t >= world.day2_start
    assert p.revisited is not None and p.revisited >= world.day2_start
    text = p.sentence()
    assert f"looked at again at {fmt_time(p.revisited)}" in text and "without it: moved" in text
    for h in p.revisits:  # every revisit is a day-2 view without the box ...
        assert h.memory.t >= world.day2_start and not world.showed(h.memory.id, RED)
    # ... and the first would have shown it, had it stayed (the day-1 world rendered from that pose)
    first = p.revisits[0].memory.pose
    assert RED in world.day1.render(first.x, first.y, first.yaw)[2]


def test_a_removed_box_is_gone(world: World) -> None:
    w = world.mem.last_seen("green box")
    assert w.status == "gone" and w.now is None and w.places
    assert all(p.last.t < world.day2_start for p in w.places)
    assert {p.verdict for p in w.places} <= {"gone", "not revisited"} and w.places[0].verdict == "gone"
    latest = w.latest
    assert latest is not None and latest.revisited is not None and latest.revisited >= world.day2_start
    assert "not seen anywhere since" in latest.sentence()


def test_an_unchanged_box_stays(world: World) -> None:
    w = world.mem.last_seen("blue box")
    assert w.status == "still there" and w.now is w.places[0]
    assert all(p.verdict in ("still there", "not revisited") for p in w.places)
    assert w.now.last.t >= world.day2_start and w.now.later_visit
    assert _dist(w.now.last, (12.5, 1.5)) < 4.0


def test_as_of_the_first_day_the_red_box_was_at_a(world: World) -> None:
    w = world.mem.last_seen("red box", before=world.day2_start - 1)
    assert w.now is not None and w.now.last.t < world.day2_start
    assert all(p.verdict in ("still there", "not revisited") for p in w.places)
    assert _dist(w.now.best.memory, A) < 3.0


def test_offline_reasoner_answers_now_and_then(world: World) -> None:
    r = OfflineReasoner(world.mem)
    now = r.ask("Where is the red box now?")
    assert now.found and now.position is not None and math.dist(now.position[:2], B) < 4.0
    assert now.time is not None and now.time >= world.day2_start
    assert any(c.verdict == "moved" and c.revisited and c.revisited >= world.day2_start for c in now.changes)
    assert "was looked at again" in now.text and "without it" in now.text
    start = r.ask("Where was the red box at the start?")
    assert start.found and start.position is not None and math.dist(start.position[:2], A) < 3.0
    assert start.time is not None and start.time < world.day2_start and start.changes == []
    plain = r.ask("Where is the red box?")  # its best views are of place A, which the robot saw empty
    assert plain.position is not None and math.dist(plain.position[:2], B) < 4.0
    assert any("later saw without it" in n for n in plain.reasoning.split("; "))
    gone = r.ask("Is the green box still there?")
    assert gone.yes is False and not gone.found and gone.position is None
    assert "not seen since" in gone.text and gone.changes and gone.changes[0].status == "gone"
    assert all(e.t < world.day2_start or not world.showed(e.id, GREEN) for e in gone.evidence)
    stays = r.ask("Is the blue box still there?")
    assert stays.yes is True and stays.changes and stays.changes[0].verdict == "still there"
    moved = r.ask("Is the red box still there?")
    assert moved.yes is False and moved.text.startswith("No: red box moved")


def _first_id(body: dict[str, Any]) -> int:
    """The first memory id in the last tool result the model was sent."""
    tool_msgs = [m["content"] for m in body["messages"] if m.get("role") == "tool"]
    m = re.search(r"\[m(\d+)\]", tool_msgs[-1])
    assert m, tool_msgs[-1]
    return int(m.group(1))


def test_the_agent_asks_for_the_latest_sightings_over_http(world: World) -> None:
    day1_end = fmt_time(world.day2_start - 1)
    script = [
        tool("search_text", query="red box", latest=True),
        lambda body: answer(
            question_type="position", answer="in the second room", evidence=[_first_id(body)]
        ),
        tool("search_text", query="red box", before=day1_end),
        lambda body: answer(question_type="position", answer="in the first room", evidence=[_first_id(body)]),
    ]
    with ScriptedModel(script) as srv:
        cfg = VLMConfig(base_url=srv.base_url, model="scripted", api_key="k", timeout=5.0, backoff=0.0)
        agent = Agent(world.mem, vlm=cfg, top_k=3, max_tool_calls=2)
        now = agent.ask("Where is the red box now?")
        props = next(t for t in srv.requests[0]["tools"] if t["function"]["name"] == "search_text")
        assert props["function"]["parameters"]["properties"]["latest"]["type"] == "boolean"
        assert "latest=true" in srv.requests[0]["messages"][0]["content"]
        shown = srv.texts(1)
        assert "newest place first" in shown and "status now: " in shown
        assert re.search(r"place \d+: moved\. .*looked at again at \S+ \(m\d+.*without it: moved", shown)
        assert "a later view of place" in shown  # the revisit views themselves, with their images
        assert now.position is not None and math.dist(now.position[:2], B) < 4.0
        assert now.changes and now.changes[0].place == 1 and now.changes[0].last_seen >= world.day2_start
        assert not any(n.startswith("warning: evidence") for n in now.notes)
        then = agent.ask("Where was the red box at the start?")
        result = [m["content"] for m in srv.requests[3]["messages"] if m.get("role") == "tool"][-1]
        assert "best first" in result and "status now" not in result and then.changes == []
        assert then.position is not None and math.dist(then.position[:2], A) < 3.0
        assert then.time is not None and then.time < world.day2_start


def test_the_agent_warns_when_it_answers_with_a_stale_place(world: World) -> None:
    w = world.mem.last_seen("red box")
    stale = next(p for p in w.places if p.verdict == "moved")
    script = [
        tool("search_text", query="red box", latest=True),
        answer(question_type="position", answer="in the first room", evidence=[stale.last.id]),
    ]
    with ScriptedModel(script) as srv:
        cfg = VLMConfig(base_url=srv.base_url, model="scripted", api_key="k", timeout=5.0, backoff=0.0)
        ans = Agent(world.mem, vlm=cfg, top_k=5, max_tool_calls=1).ask("Where is the red box now?")
    assert any(n.startswith(f"warning: evidence m{stale.last.id} is the last sighting") for n in ans.notes)
    assert [c.verdict for c in ans.changes] == ["moved"] and ans.changes[0].revisit_ids


def test_the_command_line_latest_search(world: World) -> None:
    w = world.mem.last_seen("red box")
    like = w.now.last.id if w.now else 0
    r = run_cli("search", "--like", str(like), "--latest", "-k", "3", "--memory", str(world.path), "--json")
    assert r.returncode == 0, r.stderr
    rows = json.loads(r.stdout)["results"]
    assert rows and all("change" in row for row in rows)
    verdicts = {row["change"]["verdict"] for row in rows if row["change"]["role"] == "sighting"}
    assert "moved" in verdicts and rows[0]["t"] >= world.day2_start
    r = run_cli("search", "--like", str(like), "--latest", "--memory", str(world.path))
    assert r.returncode == 0 and "status: " in r.stdout and "without it" in r.stdout
    bad = run_cli("search", "--time", "+5", "--latest", "--memory", str(world.path))
    assert "--latest applies to text and image searches" in assert_one_line_error(bad)
