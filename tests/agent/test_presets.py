"""Presets against the scripted model over HTTP: each preset's budget, k per tool, temperature and
seed show in the requests the model receives; explicit options win. The values are the RAVEN
paper's appendix table."""

from __future__ import annotations

import re

import pytest

from ravenmem.agent import PRESETS, create_method, parse_top_k
from ravenmem.errors import InputError
from tests.agent.conftest import config_for
from tests.agent.scripted_server import answer, tool

ALL5 = {"search_text": 5, "search_image": 5, "search_time": 5, "search_position": 5}
ALL1 = dict.fromkeys(ALL5, 1)


def listed(request: dict) -> list[int]:
    """How many memories each tool message of a request lists."""
    return [
        len(re.findall(r"^\[m\d+\]", m["content"], re.M)) for m in request["messages"] if m["role"] == "tool"
    ]


@pytest.mark.parametrize(
    "preset, calls, ks, temperature",
    [
        ("raven-qa-human", 3, ALL5, 0.0001),  # RAVEN-QA human-ego (irs, irs_hard)
        ("raven-qa-robot", 3, ALL5, 0.6),  # robot-ego, closed models
        ("raven-qa-robot-open", 3, ALL1, 0.5),  # robot-ego, open models: top-k 1
        ("navqa", 3, ALL5, 0.7),
        (
            "findingdory",
            15,
            {"search_text": 30, "search_image": 5, "search_time": 200, "search_position": 1},
            0.7,
        ),
    ],
)
def test_each_preset_shows_in_the_requests(mem, server, preset, calls, ks, temperature):
    server.default = tool("search_time", time="+0")  # a model that never stops searching
    agent = create_method("raven", mem, preset=preset, vlm=config_for(server), max_reasks=0)
    ans = agent.ask("What happened first?")
    choices = [r["tool_choice"] for r in server.requests]
    assert choices == ["auto"] * calls + ["none"]  # the budget, then "answer now"
    assert f"at most {calls} tool calls" in server.texts(0) and ans.cost.tool_calls == calls
    descriptions = {t["function"]["name"]: t["function"]["description"] for t in server.requests[0]["tools"]}
    assert {n: int(re.search(r"up to (\d+) memories", d)[1]) for n, d in descriptions.items()} == ks
    assert listed(server.requests[1]) == [
        min(ks["search_time"], 12)
    ]  # the time tool's k, capped by the memory
    assert {(r["temperature"], r["seed"]) for r in server.requests} == {(temperature, 0)}
    assert ans.preset == preset and ans.failed  # it never answered: an explicit failure


def test_explicit_options_override_the_preset(mem, server):
    server.push(
        tool("search_text", query="red"),
        tool("search_time", time="+0"),
        answer(question_type="text", answer="ok"),
    )
    opts = dict(top_k={"time": 7}, max_tool_calls=2, temperature=0.4, seed=9)
    ans = create_method("raven", mem, preset="findingdory", vlm=config_for(server), **opts).ask(
        "What was red?"
    )
    descriptions = {t["function"]["name"]: t["function"]["description"] for t in server.requests[0]["tools"]}
    assert (
        "up to 7 memories" in descriptions["search_time"]
        and "up to 30 memories" in descriptions["search_text"]
    )
    assert "at most 2 tool calls" in server.texts(0) and ans.cost.tool_calls == 2
    assert {(r["temperature"], r["seed"]) for r in server.requests} == {(0.4, 9)}
    assert listed(server.requests[2]) == [12, 7]  # text k=30 (12 memories held), time k=7
    # one number replaces every k of the preset
    server.push(tool("search_time", time="+0"), answer(question_type="text", answer="ok"))
    create_method("raven", mem, preset="findingdory", vlm=config_for(server), top_k=2).ask("What was first?")
    assert listed(server.requests[-1]) == [2]


def test_presets_reach_the_other_methods(mem, server):
    off = create_method("offline", mem, preset="findingdory")
    assert off.top_k == 30  # the text tool's k
    assert (
        create_method("random", mem, preset="navqa").rng.random()
        == create_method("random", mem, seed=0).rng.random()
    )
    server.push(answer(question_type="text", answer="ok"))
    create_method("vlm-only", mem, preset="navqa", vlm=config_for(server), frames=2).ask("What did I see?")
    assert (server.requests[0]["temperature"], server.requests[0]["seed"]) == (0.7, 0)
    # the VLM-only baseline's frame cap: the release's, per preset
    vlm = config_for(server)
    assert create_method("vlm-only", mem, vlm=vlm).frames == 1500
    assert create_method("vlm-only", mem, preset="findingdory", vlm=vlm).frames == 3000
    assert create_method("vlm-only", mem, preset="raven-qa-robot-open", vlm=vlm).frames == 20


def test_preset_names_and_top_k_parsing(mem):
    assert list(PRESETS) == [
        "raven-qa-human",
        "raven-qa-robot",
        "raven-qa-robot-open",
        "navqa",
        "findingdory",
    ]
    assert all(p.options()["diverse"] is False for p in PRESETS.values())  # top-k means k
    with pytest.raises(
        InputError, match="unknown preset 'dory'; choose one of: raven-qa-human, raven-qa-robot"
    ):
        create_method("offline", mem, preset="dory")
    with pytest.raises(InputError, match="preset 'raven-qa': the paper's table has one per kind of video"):
        create_method("offline", mem, preset="raven-qa")
    assert parse_top_k("5") == 5 and parse_top_k(None) is None
    assert parse_top_k("text=30, time=200,position=1") == {"text": 30, "time": 200, "position": 1}
    for bad in ("time=lots", "=3", "five", ","):
        with pytest.raises(InputError, match="--top-k"):
            parse_top_k(bad)


def test_a_presets_retrieval_returns_the_raw_top_k(tmp_path, server):
    """The paper's top-k is exactly k: with a preset (diverse=False) the text and image tools
    return the k best matches, near-duplicates included; without one they keep one view per
    moment and place; a call that says `diverse` itself wins."""
    import ravenmem
    from ravenmem.types import Frame, Pose
    from tests.agent.conftest import T0
    from tests.conftest import ColorEmbedder, solid

    # six views of red within 1.5 s at one place (near-duplicates), then green far away
    frames = [Frame(image=solid("red"), t=T0 + 0.3 * i, pose=Pose(0.0, 0.0, 0.5, 0.0)) for i in range(6)]
    frames.append(Frame(image=solid("green"), t=T0 + 60, pose=Pose(5.0, 0.0, 0.5, 0.0)))
    mem = ravenmem.create(tmp_path / "dup.mem", embedder=ColorEmbedder(), ocr=False, thumb_size=32)
    try:
        mem.add_frames(frames)

        def hits(**opts) -> list[int]:
            server.push(
                tool("search_text", query="red"),
                tool("search_text", query="red", diverse=True),
                answer(question_type="text", answer="red"),
            )
            create_method("raven", mem, vlm=config_for(server), top_k=5, **opts).ask("What was red?")
            return listed(server.requests[-1])

        assert hits(preset="navqa") == [5, 2]  # the raw top-5; the second call said diverse=true
        assert hits()[0] == 2  # one red view and green: near-duplicates dropped
        assert hits(preset="navqa", diverse=True)[0] == 2  # an explicit option beats the preset
        assert hits(diverse=False)[0] == 5
    finally:
        mem.close()
