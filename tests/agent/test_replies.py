"""The reply corpus (`reply_corpus.py`) over real HTTP: every shape gives a correct parse or a
failed answer with one named reason; through the agent, the `ravenmem ask` command (no
traceback, exit 1 with the reason) and `POST /ask` (a non-2xx with the reason, never a 500)."""

from __future__ import annotations

import json

import pytest

from ravenmem.agent import Agent, VLMConfig
from tests.agent.conftest import config_for, run_cli
from tests.agent.reply_corpus import CASES, Case, materialise
from tests.agent.scripted_server import ScriptedModel, answer, tool
from tests.agent.test_cli import ids_of


def ids_by_index(mem) -> dict[int, int]:
    return {r.frame_index: r.id for r in mem.all_records()}


@pytest.mark.parametrize("case", CASES, ids=[c.name for c in CASES])
def test_each_reply_shape_parses_or_fails_by_name(mem, case: Case):
    ids = ids_by_index(mem)
    with ScriptedModel(materialise(case, ids)) as srv:
        agent = Agent(mem, vlm=config_for(srv, **case.config), max_reasks=2)
        ans = agent.ask(case.question)
    assert agent.last_trace is not None
    if case.reason is None:
        assert case.check is not None and case.check(ans, ids), (ans.error, ans.notes, ans.position)
    else:
        assert ans.failed and not ans.found and ans.error, ans
        assert case.reason in ans.error, ans.error
        assert "\n" not in ans.error and "Traceback" not in ans.error
    # every tool call was run or rejected with a named reason
    for call in agent.last_trace["tool_calls"]:
        assert call["ok"] or call["reason"], call
    json.dumps(ans.model_dump(mode="json"), allow_nan=False)  # the answer is valid JSON


NASTY = [c for c in CASES if c.name in ("message null", "a 200 with an HTML body", "a duration of 1e308")]


@pytest.fixture
def cli(color_plugin, tmp_path):
    home = tmp_path / "home"
    return lambda *args, **kw: run_cli(*args, site=color_plugin, home=home, **kw)


def ask_cli(cli, mem_path, srv: ScriptedModel, question: str, *extra: str):
    """`ravenmem ask QUESTION -m MEMORY` against the scripted model, with `extra` flags."""
    return cli("ask", question, "-m", str(mem_path), "--base-url", srv.base_url, "--model", "m", *extra)


@pytest.mark.parametrize("case", NASTY, ids=[c.name for c in NASTY])
def test_the_command_fails_such_questions_with_one_line_and_exit_1(cli, mem_path, case: Case):
    ids = ids_of(mem_path)
    with ScriptedModel(materialise(case, ids)) as srv:
        r = ask_cli(cli, mem_path, srv, case.question, "--max-retries", "0")
    assert r.returncode == 1, (r.stdout[-2000:], r.stderr[-2000:])
    assert "Traceback" not in r.stderr and "Traceback" not in r.stdout
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("the question failed: ") and case.reason in lines[0], lines
    assert "FAILED" in r.stdout  # the answer card says so too


def test_a_text_answer_with_strings_for_numbers_through_the_command(cli, mem_path):
    ids = ids_of(mem_path)
    script = [
        tool("search_time", time="+70"),
        {
            "content": json.dumps(
                {
                    "question_type": "position",
                    "answer": "There.",
                    "evidence": [str(ids[7])],
                    "position": "[7.1,3.0,0.5]",
                    "yaw": "3.14",
                }
            )
        },
    ]
    with ScriptedModel(script) as srv:
        r = ask_cli(cli, mem_path, srv, "Where is the magenta box?", "--json")
    assert r.returncode == 0, r.stderr
    data = json.loads(r.stdout)
    assert data["position"] == [7.1, 3.0, 0.5] and data["yaw"] == pytest.approx(3.14)  # radians
    assert data["yaw_source"] == "model" and not data["unsupported"]


def test_post_ask_answers_failures_with_a_non_2xx_and_one_line(tmp_path):
    from tests.server.conftest import make_memory, serve_memory

    for case in NASTY:
        with ScriptedModel(materialise(case, {i: i + 1 for i in range(12)})) as srv:
            cfg = VLMConfig(base_url=srv.base_url, model="m", api_key="k", timeout=5, max_retries=0)
            for s in serve_memory(make_memory(tmp_path / f"{len(case.name)}.mem"), vlm=cfg):
                with s.client() as c:
                    r = c.post("/ask", json={"question": case.question})
            assert r.status_code == 502, (case.name, r.status_code, r.text)
            body = r.json()
            assert body["error"].startswith("the question failed: ") and case.reason in body["error"]
            assert "\n" not in body["error"] and body["answer"]["failed"] is True


def test_gemini_and_ollama_differences_are_settings(mem):
    ids = ids_by_index(mem)
    box = answer(question_type="position", answer="There.", evidence=[ids[7]])
    # gemini: no seed (its endpoint refuses the field), empty tool call ids, no response_format with tools
    with ScriptedModel(
        [{"tool_calls": [{"name": "search_time", "arguments": {"time": "+70"}, "id": ""}]}, box]
    ) as srv:
        agent = Agent(mem, vlm=config_for(srv, provider="gemini", seed=3), max_tool_calls=1)
        ans = agent.ask("Where is the magenta box?")
        first, second = srv.requests
    assert not ans.failed and [e.id for e in ans.evidence] == [ids[7]]
    assert "seed" not in first and "seed" not in second
    assert "response_format" not in first and first["tool_choice"] == "auto"
    call_id = second["messages"][2]["tool_calls"][0]["id"]
    assert call_id and [m["tool_call_id"] for m in second["messages"] if m["role"] == "tool"] == [call_id]
    # after the budget: no tools, the answer constrained by the schema
    assert "tools" not in second and second["response_format"]["type"] == "json_schema"
    assert second["response_format"]["json_schema"]["schema"]["required"] == [
        "question_type",
        "answer",
        "evidence",
        "found",
    ]
    # ollama: tool_choice is ignored there, so it is never sent, and no tools once the budget is spent
    with ScriptedModel([tool("search_time", time="+70"), box]) as srv:
        Agent(mem, vlm=config_for(srv, provider="ollama"), max_tool_calls=1).ask("Where is the magenta box?")
        first, second = srv.requests
    assert "tool_choice" not in first and first["tools"] and "tools" not in second
    # explicit settings win over the provider's
    cfg = VLMConfig(
        model="m", provider="llama.cpp", tool_mode="native", response_format="none", first_tool="none"
    )
    assert (cfg.tool_mode, cfg.response_format, cfg.first_tool) == ("native", "none", None)
    cfg = VLMConfig(model="m", provider="llama.cpp")
    assert (cfg.tool_mode, cfg.response_format, cfg.first_tool) == (
        "json",
        "json_object_schema",
        "search_text",
    )
