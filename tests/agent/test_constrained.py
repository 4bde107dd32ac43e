"""Constrained decoding as the agent asks for it (the llama.cpp profile and the native variant):
which schema each request carries, against a scripted server over HTTP."""

from __future__ import annotations

import json

from ravenmem.agent import Agent
from tests.agent.conftest import config_for
from tests.agent.scripted_server import ScriptedModel, answer, content, json_tool, tool


def ids_by_index(mem) -> dict[int, int]:
    return {r.frame_index: r.id for r in mem.all_records()}


def schema_of(body: dict) -> dict:
    rf = body["response_format"]
    assert rf["type"] == "json_object"  # llama.cpp's form: {"type": "json_object", "schema": ...}
    return rf["schema"]


def test_llama_cpp_profile_constrains_every_step(mem):
    ids = ids_by_index(mem)
    script = [
        json_tool("search_text", query="magenta"),
        json_tool("search_time", time="+70"),
        answer(question_type="position", answer="There.", evidence=[ids[7]], found=True),
    ]
    with ScriptedModel(script) as srv:
        ans = Agent(mem, vlm=config_for(srv, provider="llama.cpp", vision=False), max_tool_calls=2).ask(
            "Where is the magenta box?"
        )
        first, second, third = srv.requests
    assert not ans.failed and [e.id for e in ans.evidence] == [ids[7]]
    assert all("tools" not in r and "tool_choice" not in r for r in srv.requests)  # the JSON protocol
    # step 1: a search_text call only, its required argument only (the forced first search)
    s1 = schema_of(first)
    assert s1["properties"]["tool"] == {"const": "search_text"}
    assert s1["properties"]["arguments"]["required"] == ["query"]
    assert list(s1["properties"]["arguments"]["properties"]) == ["query"]
    assert s1["properties"]["arguments"]["properties"]["query"]["maxLength"] == 200
    # step 2: any of the four tools or the answer; bounded lists
    s2 = schema_of(second)
    kinds = [o["properties"].get("tool", {}).get("const", "answer") for o in s2["anyOf"]]
    assert kinds == ["search_text", "search_image", "search_time", "search_position", "answer"]
    near = s2["anyOf"][0]["properties"]["arguments"]["properties"]["near"]
    assert (near["minItems"], near["maxItems"]) == (3, 3)
    # budget spent: the answer object alone, with only what every answer has required
    s3 = schema_of(third)
    assert s3["required"] == ["question_type", "answer", "evidence", "found"]
    assert s3["properties"]["answer"]["maxLength"] == 200 and s3["additionalProperties"] is False
    # the prompt names the tools without repeating the schema the server enforces
    system = first["messages"][0]["content"]
    assert "- search_text(query, after?, before?, near?, latest?, diverse?):" in system
    assert "Arguments (JSON schema)" not in system


def test_a_prose_reply_is_reasked_with_the_answer_schema_and_a_bare_answer_with_a_tool(mem):
    ids = ids_by_index(mem)
    script = [
        answer(question_type="position", answer="Somewhere.", evidence=[]),  # answers before searching
        tool("search_time", time="+70"),
        content("The magenta box was left by the camera."),  # prose
        answer(question_type="position", answer="There.", evidence=[ids[7]]),
    ]
    with ScriptedModel(script) as srv:
        cfg = config_for(srv, tool_mode="native", response_format="json_schema", vision=False)
        ans = Agent(mem, vlm=cfg, max_tool_calls=2).ask("Where is the magenta box?")
        r = srv.requests
    assert not ans.failed and [e.id for e in ans.evidence] == [ids[7]]
    assert r[0]["tool_choice"] == "auto" and r[1]["tool_choice"] == "auto"  # re-asked to search
    assert "must rest on memories" in json.dumps(r[1]["messages"][-1])
    assert "tools" in r[2]  # budget left: tools again
    assert "tools" not in r[3] and r[3]["response_format"]["json_schema"]["name"] == "memory_answer"


def test_native_first_tool_is_a_named_tool_choice(mem):
    ids = ids_by_index(mem)
    script = [tool("search_text", query="magenta"), answer(question_type="position", evidence=[ids[7]])]
    with ScriptedModel(script) as srv:
        cfg = config_for(srv, tool_mode="native", first_tool="search_text", vision=False)
        Agent(mem, vlm=cfg).ask("Where is the magenta box?")
        first, second = srv.requests
    assert first["tool_choice"] == {"type": "function", "function": {"name": "search_text"}}
    assert second["tool_choice"] == "auto"
