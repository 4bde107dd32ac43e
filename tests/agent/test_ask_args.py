"""The ask request is declared once (`runtime.ask.AskArgs`) and every front end's schema is made
from it: the HTTP body in the live app's /openapi.json, the MCP `ask` tool's input schema as an
MCP client lists it, the fields of `ravenmem_msgs/srv/Ask` and the options of `ravenmem ask`.
A wrong value is refused at every door, whatever the method."""

from __future__ import annotations

import json
from typing import Any

import anyio
import httpx
import pytest
import typer
from mcp import Client

from ravenmem.cli.agent import ASK_OPTIONS
from ravenmem.cli.main import app
from ravenmem.ros.services import ASK_FIELDS, ServiceBackend, ask_reply, interface_texts
from ravenmem.runtime.ask import MAX_QUESTION, AskArgs, input_schema
from tests.agent.conftest import run_cli
from tests.server.conftest import make_memory, serve_memory

FIELDS = set(AskArgs.model_fields)
LONG = "where is it? " * (MAX_QUESTION // 10)  # past the bound


def plain(schema: dict[str, Any], defs: dict[str, Any]) -> dict[str, Any]:
    """A property's schema without its null branch (how OpenAPI spells "may be left out"),
    `$ref`s resolved, without titles and defaults: what the value may be."""
    if "$ref" in schema:
        schema = defs[schema["$ref"].rsplit("/", 1)[1]]
    branches = [b for b in schema.get("anyOf", []) if b.get("type") != "null"]
    if "anyOf" in schema and len(branches) == 1:
        schema = {**branches[0], **{k: v for k, v in schema.items() if k != "anyOf"}}
    drop = ("title", "default", "description", "enum")
    return {k: float(v) if isinstance(v, int | float) else v for k, v in schema.items() if k not in drop}


def test_every_front_end_schema_is_made_from_ask_args(tmp_path):
    want = input_schema()
    assert set(want["properties"]) == FIELDS and want["required"] == ["question"]
    assert want["properties"]["question"]["maxLength"] == MAX_QUESTION
    assert want["additionalProperties"] is False

    async def listed(url: str) -> dict[str, Any]:
        async with Client(f"{url}/mcp", read_timeout_seconds=60) as client:
            tools = (await client.list_tools()).tools
        return next(t.input_schema for t in tools if t.name == "ask")

    for s in serve_memory(make_memory(tmp_path / "m.mem")):
        spec = httpx.get(f"{s.url}/openapi.json", timeout=30).json()
        mcp_schema = anyio.run(listed, s.url)
    # HTTP: the body of POST /ask is AskArgs, field by field (types, bounds, required)
    body = spec["paths"]["/ask"]["post"]["requestBody"]["content"]["application/json"]["schema"]
    defs = spec["components"]["schemas"]
    http = defs[body["$ref"].rsplit("/", 1)[1]]
    assert set(http["properties"]) == FIELDS and http["required"] == ["question"]
    assert http["additionalProperties"] is False
    for name, prop in want["properties"].items():
        assert plain(http["properties"][name], defs) == plain(prop, defs), name
    # MCP: the ask tool's input schema is AskArgs' (the default method named in its description)
    assert set(mcp_schema["properties"]) == FIELDS and mcp_schema["required"] == ["question"]
    for name, prop in want["properties"].items():
        assert plain(mcp_schema["properties"][name], {}) == plain(prop, {}), name
        assert mcp_schema["properties"][name].get("enum") == prop.get("enum"), name
    # ROS 2: every field of the Ask request is an AskArgs field (the picture as a sensor_msgs/Image)
    request = interface_texts()["ravenmem_msgs/srv/Ask_Request"]
    names = {line.split()[1] for line in request.splitlines() if line.strip() and not line.startswith("#")}
    assert names == {*ASK_FIELDS, "image"} and names <= FIELDS
    # the CLI: one option of `ravenmem ask` per field, and every one of them exists
    assert set(ASK_OPTIONS) == FIELDS
    command = typer.main.get_command(app).commands["ask"]  # type: ignore[attr-defined]
    flags = {o for p in command.params for o in (*p.opts, *p.secondary_opts)} | {"QUESTION"}
    assert set(ASK_OPTIONS.values()) <= flags, set(ASK_OPTIONS.values()) - flags


def test_a_question_past_the_bound_is_refused_at_every_door(tmp_path):
    mem = make_memory(tmp_path / "m.mem")
    short = {"question": "where is the yellow thing?", "method": "offline"}

    async def mcp(url: str) -> tuple[Any, Any]:
        async with Client(f"{url}/mcp", read_timeout_seconds=60) as client:
            return (
                await client.call_tool("ask", short | {"question": LONG}),
                await client.call_tool("ask", short | {"time_mode": "nope"}),
            )

    for s in serve_memory(mem):
        with s.client() as c:
            r = c.post("/ask", json=short | {"question": LONG})
            assert r.status_code == 422 and "question" in r.json()["error"] and "4000" in r.json()["error"]
            r = c.post("/ask", json=short | {"time_mode": "nope"})
            assert r.status_code == 422 and r.json()["error"].startswith("time_mode:")
            assert c.post("/ask", json=short).status_code == 200
        long_mcp, mode_mcp = anyio.run(mcp, s.url)
        reply = ask_reply(ServiceBackend(s.service), {"question": LONG})
        fine = ask_reply(ServiceBackend(s.service), {"question": short["question"]})
    assert long_mcp.is_error and "question" in long_mcp.content[0].text  # type: ignore[union-attr]
    assert mode_mcp.is_error and "time_mode" in mode_mcp.content[0].text  # type: ignore[union-attr]
    assert reply["found"] is False and "question" in reply["reason"] and "4000" in reply["reason"]
    assert fine["found"] is True and json.loads(fine["answer_json"])["method"] == "offline"


@pytest.fixture
def cli(color_plugin, tmp_path):
    home = tmp_path / "home"
    return lambda *args, **kw: run_cli(*args, site=color_plugin, home=home, **kw)


@pytest.mark.parametrize(
    ("args", "words"),
    [
        (("--provider", "nope"), "--provider: expected one of openai"),
        (("--tool-mode", "nope"), "--tool-mode: expected one of auto, native, json"),
        (("--response-format", "nope"), "--response-format: expected one of none"),
        (("--time-mode", "nope"), "time_mode"),
        (("--model", ""), "--model: must not be empty"),
        (("--image-memory-id", "999"), "999"),
    ],
)
def test_an_invalid_option_is_refused_whatever_the_method(cli, mem_path, args, words):
    """`--offline` uses no model, yet a model option with a value no model takes is an error."""
    r = cli("ask", "Where is the magenta box?", "-m", str(mem_path), "--offline", *args)
    lines = r.stderr.strip().splitlines()
    assert r.returncode == 2 and r.stdout == "" and len(lines) == 1, r.stderr
    assert words in lines[0] and "Traceback" not in r.stderr, lines


def test_a_long_question_is_refused_by_the_cli(cli, mem_path):
    r = cli("ask", LONG, "-m", str(mem_path), "--offline")
    assert r.returncode == 2 and "question" in r.stderr and str(MAX_QUESTION) in r.stderr, r.stderr
    r = cli(
        "ask",
        "Where is the magenta box?",
        "-m",
        str(mem_path),
        "--offline",
        "--json",
        "--image-memory-id",
        "7",
    )
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout)["method"] == "offline"


def test_the_status_comes_from_the_typed_outcome_not_from_words():
    """504 for a question out of time and 502 for a failed model whatever `error` says; 422 for
    an unsupported position; the failure kind is always set on a failed answer."""
    from ravenmem.agent.ask import AskResult
    from ravenmem.agent.schema import Answer

    late = Answer(failed=True, failure="out_of_time", error="the model said nothing")
    broken = Answer(failed=True, error="out of time (the words of a model's reply)")
    assert AskResult(late, refusal="x").status == 504 and AskResult(late).outcome == "out_of_time"
    assert broken.failure == "model_failed" and AskResult(broken, refusal="x").status == 502
    assert AskResult(Answer(unsupported=True), refusal="unsupported answer").status == 422
    assert AskResult(Answer()).status == 200 and Answer(failure="no_answer").failure is None


def test_the_agent_takes_method_options_as_they_are(mem_path, server):
    """`Agent(memory, options)`: the preset is applied once (`with_preset` says so), and the
    options a question sets win over the preset's."""
    import ravenmem
    from ravenmem.agent import MethodOptions
    from ravenmem.agent.loop import Agent
    from tests.agent.conftest import config_for

    opts = MethodOptions(method="raven", vlm=config_for(server), preset="findingdory", top_k={"text": 2})
    applied = opts.with_preset()
    assert applied.preset_applied and applied.with_preset() is applied
    with ravenmem.open(mem_path) as mem:
        agent = Agent(mem, opts)
        same = Agent(mem, applied)
        kw = Agent(mem, vlm=config_for(server), preset="findingdory", top_k={"text": 2})
    assert agent.ks == same.ks == kw.ks and agent.ks["search_text"] == 2
    assert agent.max_tool_calls == applied.max_tool_calls and agent.preset == "findingdory"
