"""The agent's progress hook: one typed `ToolStep` per tool call (run or refused), in the
order of the answer's trace, through `Service.ask` to its caller and to the event stream."""

from __future__ import annotations

from typing import Any

from ravenmem.agent import Agent
from ravenmem.agent.progress import ToolStep
from ravenmem.runtime.ask import AskArgs
from ravenmem.runtime.service import Service, ServiceConfig
from tests.agent.conftest import config_for
from tests.agent.scripted_server import answer, tool, tools


def ids_by_index(mem) -> dict[int, int]:
    return {r.frame_index: r.id for r in mem.all_records()}


def test_one_step_per_tool_call_run_or_refused_as_the_trace_records_them(mem, server):
    ids = ids_by_index(mem)
    server.push(
        tool("search_text", query="red"),
        tool("fly_to", x=1),  # unknown: refused with its reason
        tools(("search_time", {"time": "+0"}), ("search_text", {"query": "ball"})),  # the 2nd: over budget
        answer(question_type="position", evidence=[ids[1]]),
    )
    agent = Agent(mem, vlm=config_for(server), max_tool_calls=3, top_k=4)
    steps: list[ToolStep] = []
    agent.progress = steps.append
    ans = agent.ask("Where is the red ball?")
    assert not ans.failed
    trace = agent.last_trace
    assert trace is not None
    assert len(steps) == len(trace["tool_calls"]) == 4
    # the answer's counts: calls within the budget (run, or failed when run) and refused ones
    assert sum(1 for s in steps if s.reason != "the tool budget is spent") == ans.cost.tool_calls == 3
    assert sum(1 for s in steps if not s.ok) == ans.cost.tool_calls_rejected == 2
    assert [s.step for s in steps] == [1, 2, 3, 4]
    assert [s.tool for s in steps] == [c["name"] for c in trace["tool_calls"]]
    assert [s.ok for s in steps] == [c["ok"] for c in trace["tool_calls"]] == [True, False, True, False]
    assert [s.arguments for s in steps] == [c["arguments"] for c in trace["tool_calls"]]
    assert steps[0].hits == 4 and '"red"' in steps[0].arguments  # k=4 memories returned
    assert steps[1].hits == 0 and "unknown tool 'fly_to'" in (steps[1].reason or "")
    assert steps[3].reason == "the tool budget is spent" and steps[3].hits == 0


def test_a_failing_callback_does_not_fail_the_question(mem, server):
    ids = ids_by_index(mem)
    server.push(tool("search_text", query="red"), answer(question_type="position", evidence=[ids[1]]))
    agent = Agent(mem, vlm=config_for(server))

    def broken(_step: ToolStep) -> None:
        raise RuntimeError("the display is gone")

    agent.progress = broken
    ans = agent.ask("Where is the red ball?")
    assert not ans.failed and ans.found and ans.cost.tool_calls == 1


def test_service_ask_hands_each_step_to_the_caller_and_the_event_stream(mem, server):
    ids = ids_by_index(mem)
    server.push(
        tool("search_text", query="red"),
        tool("search_time", time="+0"),
        answer(question_type="position", evidence=[ids[1]]),
    )
    svc = Service(mem, ServiceConfig(vlm=config_for(server), writable=False))
    events: list[tuple[str, dict[str, Any]]] = []
    svc.bus.publish = lambda kind, data: events.append((kind, data))  # type: ignore[method-assign]
    steps: list[ToolStep] = []
    result = svc.ask(AskArgs(question="Where is the red ball?"), progress=steps.append)
    assert result.answer.method == "raven" and result.answer.cost.tool_calls == 2
    assert [(s.step, s.tool, s.ok) for s in steps] == [(1, "search_text", True), (2, "search_time", True)]
    calls = [d for k, d in events if k == "tool_call"]
    assert [d["tool"] for d in calls] == ["search_text", "search_time"]
    assert calls[0]["question"] == "Where is the red ball?" and calls[0]["hits"] == steps[0].hits > 0
    assert [k for k, _ in events][-1] == "answer"  # the steps come before the answer
    # a method without tool calls reports nothing, and answers as before
    quiet: list[ToolStep] = []
    offline = svc.ask(
        AskArgs(question="where is the red ball?", method="embedder-only"), progress=quiet.append
    )
    assert quiet == [] and offline.answer.method == "embedder-only"
