"""The agent loop against a scripted model over real HTTP: tools, images, budget, order, failures."""

from __future__ import annotations

import json
import math
import re

import pytest

from ravenmem.agent import Agent, VLMConfig
from ravenmem.errors import InputError
from tests.agent.conftest import T0, config_for
from tests.agent.scripted_server import answer, content, error, json_tool, refuse, tool, tools
from tests.conftest import solid


def ids_by_index(mem) -> dict[int, int]:
    return {r.frame_index: r.id for r in mem.all_records()}


def test_native_loop_offers_tools_attaches_images_and_answers_from_evidence(mem, server):
    ids = ids_by_index(mem)
    server.push(
        tool("search_text", query="red backpack"),
        answer(
            question_type="position", answer="Near the magenta wall.", evidence=[ids[8]], reasoning="seen"
        ),
    )
    agent = Agent(mem, vlm=config_for(server))
    ans = agent.ask("Where did I leave the red backpack?")
    assert not ans.failed and ans.found and ans.method == "raven"
    assert len(server.requests) == 2
    r0, r1 = server.requests
    assert server.tool_names(0) == ["search_text", "search_image", "search_time", "search_position"]
    assert r0["tool_choice"] == "auto" and server.images(0) == 0
    assert r0["temperature"] == 0.0 and "seed" not in r0  # the config's defaults: no seed set
    assert "Where did I leave the red backpack?" in server.texts(0)
    # the tool result: one tool message answering the call, 5 memories with time, pose and score
    call_id = r1["messages"][2]["tool_calls"][0]["id"]
    tool_msgs = [m for m in r1["messages"] if m["role"] == "tool"]
    assert [m["tool_call_id"] for m in tool_msgs] == [call_id]
    text = tool_msgs[0]["content"]
    assert len(re.findall(r"^\[m\d+\]", text, re.M)) == 5
    assert f"[m{ids[1]}]" in text and f"[m{ids[8]}]" in text and "score 1.000" in text
    assert "pose x=8.00 y=3.00 z=0.50" in text and "+80.0 s" in text
    assert server.images(1) == 5  # one image per new memory
    # the answer: the model gave no position or heading, so both come from the evidence camera
    assert ans.question_type == "position" and ans.position_source == ans.yaw_source == "evidence"
    assert ans.position == pytest.approx([8.0, 3.0, 0.5]) and ans.yaw == pytest.approx(0.8)
    assert any("no position given" in n and f"m{ids[8]}" in n for n in ans.notes)
    assert any("no heading given" in n and "46 deg" in n for n in ans.notes)
    assert (ans.model, ans.embedder) == ("scripted-vlm", "test-color")
    assert ans.model_host == server.base_url.split("/")[2] and ans.preset is None
    assert ans.time == pytest.approx(T0 + 80) and [e.id for e in ans.evidence] == [ids[8]]
    assert ans.evidence[0].score == pytest.approx(1.0, abs=1e-4)
    c = ans.cost
    assert (c.tool_calls, c.memories_shown, c.memories_total, c.images) == (1, 5, 12, 5)
    assert c.image_bytes == sum(
        (mem.path / h.memory.image_path).stat().st_size for h in mem.search_text("red", k=5)
    )
    assert (
        c.alpha == pytest.approx(5 / 12) and c.prompt_tokens > 0 and c.completion_tokens > 0 and c.wall_s > 0
    )


def test_query_image_offers_the_image_tool(mem, server):
    ids = ids_by_index(mem)
    server.push(tool("search_image"), answer(question_type="position", evidence=[ids[10]]))
    ans = Agent(mem, vlm=config_for(server), top_k=3).ask("Where did I see this?", image=solid("blue"))
    assert "search_image" in server.tool_names(0)
    assert "search_image without memory_id searches with the image attached" in server.texts(0)
    assert server.images(0) == 1  # the user's image
    text = next(m["content"] for m in server.requests[1]["messages"] if m["role"] == "tool")
    assert [int(i) for i in re.findall(r"^\[m(\d+)\]", text, re.M)] == sorted(
        [ids[3], ids[6], ids[10]]
    ) or set(int(i) for i in re.findall(r"^\[m(\d+)\]", text, re.M)) == {ids[3], ids[6], ids[10]}
    assert ans.position == pytest.approx([10.0, 4.0, 0.5]) and ans.cost.images == 4


def test_duplicates_are_not_resent(mem, server):
    server.push(
        tool("search_text", query="red"),
        tool("search_text", query="magenta"),
        answer(question_type="text", answer="done", evidence=[]),
    )
    first = {h.memory.id for h in mem.search_text("red", k=3)}
    second = {h.memory.id for h in mem.search_text("magenta", k=3)}
    assert first & second and second - first  # overlap and news: the case under test
    ans = Agent(mem, vlm=config_for(server), top_k=3).ask("What colour was the wall?")
    assert server.images(1) == 3
    assert server.images(2) == 3 + len(second - first)  # history keeps the old images, adds only new ones
    last_tool = [m for m in server.requests[2]["messages"] if m["role"] == "tool"][-1]["content"]
    assert last_tool.count("(already shown above)") == len(first & second)
    assert ans.cost.memories_shown == len(first | second) and ans.cost.images == len(first | second)


def test_time_results_are_chronological(mem, server):
    ids = ids_by_index(mem)
    server.push(tool("search_time", time="+25"), answer(question_type="time", evidence=[ids[3]]))
    ans = Agent(mem, vlm=config_for(server)).ask("What did I see after 25 seconds?")
    text = next(m["content"] for m in server.requests[1]["messages"] if m["role"] == "tool")
    assert "chronological" in text
    shown = [int(i) for i in re.findall(r"^\[m(\d+)\]", text, re.M)]
    assert shown == [ids[i] for i in (3, 4, 5, 6, 7)]
    offsets = [float(x) for x in re.findall(r"\(\+([\d.]+) s\)", text)]
    assert offsets == sorted(offsets) == [30.0, 40.0, 50.0, 60.0, 70.0]
    assert ans.time == pytest.approx(T0 + 30)
    assert ans.embedder is None and ans.model == "scripted-vlm"  # only the time tool ran: no embedder


def test_position_tool_and_model_time_strings(mem, server):
    ids = ids_by_index(mem)
    server.push(
        tool("search_position", x=8.1, y=3.0, radius=2.0),
        answer(question_type="time", evidence=[ids[8]], time="2023-11-14T22:14:40Z"),
    )
    ans = Agent(mem, vlm=config_for(server)).ask("When was I at the corner?")
    text = next(m["content"] for m in server.requests[1]["messages"] if m["role"] == "tool")
    assert "nearest first" in text and "distance 0.10 m" in text
    assert ans.time == pytest.approx(1700000080.0)


def test_budget_is_enforced_against_a_model_that_never_stops_calling_tools(mem, server):
    server.default = tool("search_text", query="red")
    agent = Agent(mem, vlm=config_for(server), max_tool_calls=2, max_reasks=2)
    ans = agent.ask("Where is the red ball?")
    assert ans.failed and not ans.found and "tool budget" in (ans.error or "")
    assert ans.cost.tool_calls == 2
    assert len(server.requests) == 5  # 2 tool turns + 3 answers refused
    assert [r["tool_choice"] for r in server.requests] == ["auto", "auto", "none", "none", "none"]
    assert "used all 2 tool calls" in server.texts(2)
    # every call got a tool message, the unrun ones say so
    last = server.requests[-1]["messages"]
    unanswered = {c["id"] for m in last if m.get("tool_calls") for c in m["tool_calls"]} - {
        m["tool_call_id"] for m in last if m["role"] == "tool"
    }
    assert not unanswered
    assert sum(1 for m in last if m["role"] == "tool" and "not run" in m["content"]) == 2
    assert ans.evidence  # what was retrieved is still reported


def test_budget_spent_then_answer_without_tools(mem, server):
    ids = ids_by_index(mem)
    server.push(
        tools(("search_text", {"query": "red"}), ("search_time", {"time": "+0"})),
        answer(question_type="position", evidence=[ids[1]]),
    )
    ans = Agent(mem, vlm=config_for(server), max_tool_calls=1).ask("Where is the red ball?")
    assert not ans.failed and ans.cost.tool_calls == 1
    msgs = server.requests[1]["messages"]
    tool_msgs = [m["content"] for m in msgs if m["role"] == "tool"]
    assert len(tool_msgs) == 2 and "not run" in tool_msgs[1]
    assert server.requests[1]["tool_choice"] == "none" and "used all 1 tool calls" in server.texts(1)


def test_bad_tool_arguments_come_back_as_errors_the_model_can_fix(mem, server):
    ids = ids_by_index(mem)
    server.push(
        tool("search_text"),
        tool("fly_to", x=1),
        tool("search_text", query="red"),
        answer(question_type="position", evidence=[ids[1]]),
    )
    ans = Agent(mem, vlm=config_for(server), max_tool_calls=3).ask("Where is the red ball?")
    tool_msgs = [m["content"] for m in server.requests[3]["messages"] if m["role"] == "tool"]
    assert tool_msgs[0].startswith("error: search_text could not run") and "query" in tool_msgs[0]
    assert tool_msgs[1].startswith("error: unknown tool 'fly_to'")
    assert not ans.failed and ans.cost.tool_calls == 3


def test_malformed_json_is_reasked_then_accepted(mem, server):
    ids = ids_by_index(mem)
    server.push(
        tool("search_text", query="red"),
        content("The red ball is near the wall, I think."),
        content(
            f'```json\n{{"question_type": "position", "evidence": ["m{ids[8]}"], "answer": "there"}}\n```'
        ),
    )
    ans = Agent(mem, vlm=config_for(server)).ask("Where is the red ball?")
    assert not ans.failed and ans.evidence[0].id == ids[8] and ans.text == "there"
    assert "could not be used: no JSON object" in server.texts(2)


def test_malformed_forever_is_an_explicit_failure(mem, server):
    server.default = content("{not json at all")
    ans = Agent(mem, vlm=config_for(server), max_reasks=2).ask("When did I see the blue box?")
    assert ans.failed and ans.question_type == "time" and "no JSON object" in (ans.error or "")
    assert len(server.requests) == 3 and ans.position is None and ans.time is None


def test_invalid_fields_are_reasked_with_the_reason(mem, server):
    ids = ids_by_index(mem)
    server.push(
        tool("search_text", query="red"),
        answer(question_type="position", position="kitchen", evidence=[ids[1]]),
        answer(question_type="position", evidence=[ids[1]]),
    )
    ans = Agent(mem, vlm=config_for(server)).ask("Where is the red ball?")
    assert not ans.failed and "invalid answer fields (position" in server.texts(2)


def test_refusal_then_answer_and_refusal_forever(mem, server):
    ids = ids_by_index(mem)
    server.push(
        tool("search_text", query="red"),
        refuse(),
        answer(question_type="binary", yes=True, evidence=[ids[1]]),
    )
    ans = Agent(mem, vlm=config_for(server)).ask("Did I see a red ball?")
    assert not ans.failed and ans.yes is True and "the model refused" in server.texts(2)
    server.requests.clear()
    server.default = refuse("I cannot help with that.")
    ans = Agent(mem, vlm=config_for(server), max_reasks=1).ask("Did I see a red ball?")
    assert ans.failed and "refused: I cannot help with that." in (ans.error or "")


def test_position_answer_missing_coordinates_uses_best_evidence(mem, server):
    ids = ids_by_index(mem)
    server.push(tool("search_text", query="magenta"), answer(question_type="position", answer="It is there."))
    ans = Agent(mem, vlm=config_for(server)).ask("Where is the magenta box?")
    assert ans.position_source == "evidence" and ans.position == pytest.approx([7.0, 3.0, 0.5])
    assert [e.id for e in ans.evidence] == [ids[7]] and any("no evidence named" in n for n in ans.notes)


def test_the_model_chooses_position_and_heading(mem, server):
    ids = ids_by_index(mem)
    server.push(
        tool("search_text", query="red"),
        answer(question_type="position", evidence=[ids[8]], position=[8.5, 3.2, 0.4], yaw_deg=90),
    )
    ans = Agent(mem, vlm=config_for(server)).ask("Where is the red ball?")
    assert (ans.position, ans.position_source) == ([8.5, 3.2, 0.4], "model")
    assert ans.yaw == pytest.approx(math.pi / 2) and ans.yaw_source == "model"
    assert not any("position" in n or "heading" in n for n in ans.notes)
    fmt = server.requests[0]["messages"][0]["content"]
    assert '"yaw_deg": null or the heading' in fmt and "in degrees counter-clockwise" in fmt
    # a heading alone: the position falls back to the evidence camera and says so; 270 deg wraps
    server.push(
        tool("search_text", query="red"), answer(question_type="position", evidence=[ids[8]], yaw_deg=270)
    )
    ans = Agent(mem, vlm=config_for(server)).ask("Where is the red ball?")
    assert ans.yaw == pytest.approx(-math.pi / 2) and ans.yaw_source == "model"
    assert ans.position_source == "evidence" and ans.position == pytest.approx([8.0, 3.0, 0.5])
    assert any("no position given" in n for n in ans.notes)


def test_the_answers_yaw_is_radians_whatever_the_model_wrote(mem, server):
    """Answer.yaw is radians in the map frame: `yaw_deg` is converted, `yaw`/`heading` are
    radians, and degrees copied into `yaw` (the listings show `yaw=90deg`) are re-asked with
    the reason, never read as radians (90 rad would face 117 deg) nor guessed."""
    ids = ids_by_index(mem)
    server.push(
        tool("search_text", query="red"),
        answer(question_type="position", evidence=[ids[8]], position=[8.5, 3.2, 0.4], yaw=90),
        answer(question_type="position", evidence=[ids[8]], position=[8.5, 3.2, 0.4], yaw_deg=90),
    )
    ans = Agent(mem, vlm=config_for(server)).ask("Where is the red ball?")
    assert "yaw 90 is more than a full turn in radians; give degrees as yaw_deg" in server.texts(2)
    assert ans.yaw == pytest.approx(math.pi / 2) and ans.yaw_source == "model"
    server.push(
        tool("search_text", query="red"),
        answer(question_type="position", evidence=[ids[8]], position=[8.5, 3.2, 0.4], heading=-1.5),
    )
    ans = Agent(mem, vlm=config_for(server)).ask("Where is the red ball?")
    assert ans.yaw == pytest.approx(-1.5) and ans.model_dump()["yaw"] == pytest.approx(-1.5)
    # no heading from the model: the evidence camera's, radians as stored (memory 8: yaw 0.8 rad)
    server.push(tool("search_text", query="red"), answer(question_type="position", evidence=[ids[8]]))
    ans = Agent(mem, vlm=config_for(server)).ask("Where is the red ball?")
    assert ans.yaw == pytest.approx(0.8) and ans.yaw_source == "evidence"


def test_a_far_model_position_is_kept_but_marked_unsupported_with_the_distance(mem, server):
    ids = ids_by_index(mem)
    server.push(
        tool("search_text", query="red"),
        answer(question_type="position", evidence=[ids[8], 9999], position=[50.0, -40.0, 0.0]),
    )
    ans = Agent(mem, vlm=config_for(server)).ask("Where is the red ball?")
    assert ans.position_source == "model" and ans.position == [50.0, -40.0, 0.0]
    assert ans.unsupported and ans.support_distance == pytest.approx(60.1, abs=0.05)
    warning = next(n for n in ans.notes if n.startswith("unsupported:"))
    assert f"(m{ids[8]})" in warning and "more than 3 m" in warning
    assert "is 60.1 m from the nearest memory shown" in warning  # |(50, -40, 0) - (8, 3, 0.5)|
    assert any("9999" in n for n in ans.notes) and [e.id for e in ans.evidence] == [ids[8]]
    assert ans.yaw_source == "evidence" and ans.yaw == pytest.approx(0.8)
    near = Agent(mem, vlm=config_for(server), max_position_offset=100.0)
    server.push(
        tool("search_text", query="red"),
        answer(question_type="position", evidence=[ids[8]], position=[50.0, -40.0, 0.0]),
    )
    ans = near.ask("Where is the red ball?")  # the threshold is a setting
    assert not ans.unsupported and ans.support_distance == pytest.approx(60.1, abs=0.05)


def test_where_answer_without_any_retrieval_is_reasked(mem, server):
    ids = ids_by_index(mem)
    server.push(
        answer(question_type="position", position=[1, 2, 3]),
        tool("search_text", query="red"),
        answer(question_type="position", evidence=[ids[1]]),
    )
    ans = Agent(mem, vlm=config_for(server)).ask("Where is the red ball?")
    assert not ans.failed and ans.position == pytest.approx([1.0, 0.0, 0.5])
    assert "must rest on memories" in server.texts(1)


def test_duration_from_evidence_span_and_binary_default(mem, server):
    ids = ids_by_index(mem)
    server.push(
        tool("search_text", query="blue"), answer(question_type="duration", evidence=[ids[3], ids[10]])
    )
    ans = Agent(mem, vlm=config_for(server)).ask("How long was the blue box in view?")
    assert ans.duration == pytest.approx(70.0)
    server.push(
        tool("search_text", query="blue"), answer(question_type="binary", evidence=[ids[3]], found=True)
    )
    assert Agent(mem, vlm=config_for(server)).ask("Did I see a blue box?").yes is True


def test_transient_http_errors_inside_the_loop(mem, server):
    ids = ids_by_index(mem)
    server.push(
        error(503),
        tool("search_text", query="red"),
        error(500),
        answer(question_type="position", evidence=[ids[1]]),
    )
    agent = Agent(mem, vlm=config_for(server))
    ans = agent.ask("Where is the red ball?")
    assert not ans.failed and agent.client is not None and agent.client.retries == 2
    assert len(server.requests) == 4


def test_timeouts_become_a_failure_answer_not_an_exception(mem, server):
    server.default = {"content": "{}", "delay": 1.0}
    ans = Agent(mem, vlm=config_for(server, timeout=0.25, max_retries=1)).ask("Where is the red ball?")
    assert (
        ans.failed
        and "timed out after 0.25 s" in (ans.error or "")
        and ans.text.startswith("I could not answer")
    )


def test_json_mode_protocol(mem, server):
    ids = ids_by_index(mem)
    server.push(json_tool("search_text", query="red"), answer(question_type="position", evidence=[ids[1]]))
    ans = Agent(mem, vlm=config_for(server, tool_mode="json")).ask("Where is the red ball?")
    assert not ans.failed and ans.cost.tool_calls == 1
    assert all("tools" not in r for r in server.requests)
    system = server.requests[0]["messages"][0]["content"]
    assert '{"tool": "<tool name>"' in system and "search_position" in system
    last_user = server.requests[1]["messages"][-1]["content"]
    assert last_user[0]["text"].startswith("Tool results:") and server.images(1) == 5


def test_auto_mode_falls_back_to_json_when_tools_are_rejected(mem, server):
    ids = ids_by_index(mem)
    server.reject_tools = True
    server.push(json_tool("search_text", query="red"), answer(question_type="position", evidence=[ids[8]]))
    agent = Agent(mem, vlm=config_for(server))
    ans = agent.ask("Where is the red ball?")
    assert not ans.failed and agent.mode == "json" and any("switched to the JSON" in n for n in ans.notes)
    assert "tools" in server.requests[0] and all("tools" not in r for r in server.requests[1:])
    n = len(server.requests)
    server.push(json_tool("search_text", query="red"), answer(question_type="position", evidence=[ids[8]]))
    assert not agent.ask("Where is the red ball?").failed
    assert all("tools" not in r for r in server.requests[n:])  # remembered: no second rejection


def test_native_mode_does_not_fall_back(mem, server):
    server.reject_tools = True
    ans = Agent(mem, vlm=config_for(server, tool_mode="native")).ask("Where is the red ball?")
    assert ans.failed and "--tool-mode json" in (ans.error or "")


def test_trace_is_saved_without_image_bytes(mem, server, tmp_path):
    ids = ids_by_index(mem)
    server.push(tool("search_text", query="red"), answer(question_type="position", evidence=[ids[1]]))
    path = tmp_path / "trace.json"
    Agent(mem, vlm=config_for(server), trace_path=path).ask("Where is the red ball?")
    raw = path.read_text()
    assert "base64" not in raw and "test-key" not in raw
    tr = json.loads(raw)
    assert tr["question"] == "Where is the red ball?" and len(tr["events"]) == 2
    assert tr["events"][1]["request"]["messages"][-1]["content"][2]["image_url"]["url"].startswith(
        "<image/jpeg"
    )
    assert tr["events"][1]["response"]["choices"][0]["message"]["content"]
    assert tr["answer"]["evidence"][0]["id"] == ids[1]
    d = tmp_path / "traces"
    d.mkdir()
    server.push(tool("search_text", query="red"), answer(question_type="position", evidence=[ids[1]]))
    Agent(mem, vlm=config_for(server), trace_path=d).ask("Where is the red ball?")
    assert len(list(d.glob("trace_*.json"))) == 1


def test_no_vlm_configured_is_a_clear_error(mem, monkeypatch, tmp_path):
    for var in ("RAVENMEM_VLM_MODEL", "RAVENMEM_VLM_BASE_URL", "RAVENMEM_CONFIG"):
        monkeypatch.delenv(var, raising=False)
    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path))
    for vlm in (None, VLMConfig()):
        with pytest.raises(InputError, match="method 'raven' needs a VLM: .*--model.*RAVENMEM_VLM_MODEL"):
            Agent(mem, vlm=vlm)


def test_bad_arguments(mem, server):
    with pytest.raises(InputError):
        Agent(mem, vlm=config_for(server), top_k=0)
    with pytest.raises(InputError, match="empty question"):
        Agent(mem, vlm=config_for(server)).ask("  ")


def test_agent_is_exported_from_the_package():
    import ravenmem
    import ravenmem.agent

    assert ravenmem.Agent is ravenmem.agent.Agent is Agent


def test_top_k_per_tool(mem, server):
    """FindingDory-style budgets: many memories from the time tool, few from the text tool."""
    server.push(
        tool("search_time", time="+0"),
        tool("search_text", query="red"),
        answer(question_type="text", answer="done", evidence=[]),
    )
    agent = Agent(mem, vlm=config_for(server), top_k={"time": 9, "text": 2}, max_tool_calls=2)
    agent.ask("What happened first?")
    specs = {t["function"]["name"]: t["function"]["description"] for t in server.requests[0]["tools"]}
    assert "up to 9 memories" in specs["search_time"] and "up to 2 memories" in specs["search_text"]
    assert "up to 5 memories" in specs["search_position"]  # not named: the default
    tool_texts = [m["content"] for m in server.requests[2]["messages"] if m["role"] == "tool"]
    assert [len(re.findall(r"^\[m\d+\]", t, re.M)) for t in tool_texts] == [9, 2]
    with pytest.raises(Exception, match="unknown tool 'colour'"):
        Agent(mem, vlm=config_for(server), top_k={"colour": 3})


def test_the_image_tool_is_always_offered_and_searches_by_memory_id(mem, server):
    ids = ids_by_index(mem)
    server.push(
        tool("search_image"),  # no image attached and no memory_id: an error the model can fix
        tool("search_image", memory_id=ids[3]),  # "more views like memory m3" (blue)
        answer(question_type="position", evidence=[ids[10]]),
    )
    ans = Agent(mem, vlm=config_for(server), top_k={"image": 2}).ask("Where else was the blue wall?")
    assert "search_image" in server.tool_names(0) and server.images(0) == 0
    spec = next(t["function"] for t in server.requests[0]["tools"] if t["function"]["name"] == "search_image")
    assert "memory_id" in spec["parameters"]["properties"] and spec["parameters"]["required"] == []
    assert "up to 2 memories" in spec["description"]
    tool_msgs = [m["content"] for m in server.requests[2]["messages"] if m["role"] == "tool"]
    assert tool_msgs[0].startswith("error: search_image could not run") and "memory_id" in tool_msgs[0]
    listed = [int(i) for i in re.findall(r"^\[m(\d+)\]", tool_msgs[1], re.M)]
    assert set(listed) == {ids[6], ids[10]} and f"memory_id={ids[3]}" in tool_msgs[1]  # not m3 itself
    assert not ans.failed and ans.position == pytest.approx([10.0, 4.0, 0.5])


def test_scores_can_be_hidden_from_the_model(mem, server):
    server.push(
        tool("search_text", query="red"),
        tool("search_position", x=1.0, y=0.0),
        answer(question_type="text", answer="done", evidence=[]),
    )
    Agent(mem, vlm=config_for(server), show_scores=False, max_tool_calls=2).ask("What was red?")
    specs = " ".join(t["function"]["description"] for t in server.requests[0]["tools"])
    assert "score" not in specs and "distance" not in specs
    assert "Scores are similarities" not in server.texts(0)
    tool_msgs = [m["content"] for m in server.requests[2]["messages"] if m["role"] == "tool"]
    assert len(re.findall(r"^\[m\d+\]", "\n".join(tool_msgs), re.M)) == 10
    assert "score" not in "\n".join(tool_msgs) and "distance" not in "\n".join(tool_msgs)
    # and shown by default
    server.push(tool("search_text", query="red"), answer(question_type="text", answer="done", evidence=[]))
    Agent(mem, vlm=config_for(server)).ask("What was red?")
    assert "score 1.000" in [m["content"] for m in server.requests[-1]["messages"] if m["role"] == "tool"][0]


def test_time_tool_forward_or_centred(mem, server):
    ids = ids_by_index(mem)
    for mode, expected in (("forward", (5, 6, 7, 8)), ("centred", (3, 4, 5, 6))):
        server.push(
            tool("search_time", time="+50s"), answer(question_type="text", answer="done", evidence=[])
        )
        Agent(mem, vlm=config_for(server), top_k=4, time_mode=mode).ask("What did I see around +50 s?")
        desc = next(
            t["function"]["description"]
            for t in server.requests[-2]["tools"]
            if "time" in t["function"]["name"]
        )
        assert ("around a given time" in desc) == (mode == "centred")
        text = next(m["content"] for m in server.requests[-1]["messages"] if m["role"] == "tool")
        assert [int(i) for i in re.findall(r"^\[m(\d+)\]", text, re.M)] == [ids[i] for i in expected]
    with pytest.raises(InputError, match="time_mode"):
        Agent(mem, vlm=config_for(server), time_mode="backwards")


def test_temperature_and_seed_reach_the_request_body(mem, server):
    server.push(tool("search_text", query="red"), answer(question_type="text", answer="ok", evidence=[]))
    Agent(mem, vlm=config_for(server, temperature=0.3, seed=11)).ask("What was red?")
    assert [(r["temperature"], r["seed"]) for r in server.requests] == [(0.3, 11), (0.3, 11)]
    server.push(tool("search_text", query="red"), answer(question_type="text", answer="ok", evidence=[]))
    Agent(mem, vlm=config_for(server, temperature=0.3, seed=11), temperature=0.9, seed=5).ask("What was red?")
    assert [(r["temperature"], r["seed"]) for r in server.requests[2:]] == [(0.9, 5), (0.9, 5)]


def test_a_question_has_a_wall_clock_deadline(mem, server):
    """Each reply arrives just inside the per-request limit, but the question as a whole must stop."""
    server.default = {**tool("search_text", query="red"), "delay": 0.6}
    agent = Agent(mem, vlm=config_for(server, timeout=2.0, question_timeout=1.5), max_tool_calls=10)
    ans = agent.ask("Where is the red ball?")
    # 10 replies of 0.6 s would take 6 s: the 1.5 s deadline stops it after a few (counted, not timed)
    assert ans.failed and 1 <= ans.cost.tool_calls <= 3 and len(server.requests) <= 4, ans.cost
    assert "out of time" in (ans.error or "")
