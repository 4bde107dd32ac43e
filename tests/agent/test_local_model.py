"""A real local model end to end: SmolLM2-135M through llama-cpp-python's server (a real process,
real weights, real tokenizer), asked by `ravenmem ask` and a small `ravenmem eval` split.

Asserted: every request is one the server takes (HTTP 200; the only exception is the one
request whose pictures the text-only model refused, after which it gets text), every tool call
is run or rejected with a named reason, the loop ends within its budget, and the answer is
parsed, or the question fails with one clear line and a non-zero exit. No accuracy target: the
model is tiny and sees no pictures.

Needs the `local` extra; skipped with the reason when it is absent, unless
RAVENMEM_REQUIRE_LOCAL_MODEL=1 (CI sets it), which makes a missing extra a failure. Marked
`local` (run with `-m local`): each question takes a minute or more on two shared cores.
"""

from __future__ import annotations

import json
import re
from collections.abc import Iterator
from pathlib import Path

import pytest

from tests.agent.conftest import run_cli
from tests.agent.local_model import MODEL_NAME, LocalModel, missing, required

pytestmark = [pytest.mark.local, pytest.mark.timeout(3600)]
MAX_TOOL_CALLS = 1
MAX_REASKS = 2
SLOW = {  # a 135M model on two shared cores, constrained by a grammar: minutes, not seconds
    "RAVENMEM_VLM_TIMEOUT": "900",
    "RAVENMEM_VLM_QUESTION_TIMEOUT": "2400",
    "RAVENMEM_VLM_MAX_TOKENS": "256",
    "RAVENMEM_VLM_MAX_RETRIES": "0",
}


@pytest.fixture(scope="module")
def local_model(tmp_path_factory) -> Iterator[LocalModel]:
    why = missing()
    if why is not None:
        if required():
            pytest.fail(f"RAVENMEM_REQUIRE_LOCAL_MODEL=1 but {why}")
        pytest.skip(why)
    with LocalModel(tmp_path_factory.mktemp("llama") / "server.log") as lm:
        yield lm


def served_requests(lm: LocalModel) -> list[int]:
    """The HTTP status of every chat completion the server answered (from its access log)."""
    return [int(s) for s in re.findall(r'"POST /v1/chat/completions HTTP/1.1" (\d{3})', lm.tail(10**7))]


@pytest.fixture
def cli(color_plugin, tmp_path):
    home = tmp_path / "home"
    return lambda *args, **kw: run_cli(*args, site=color_plugin, home=home, timeout=3000, **kw)


def test_ravenmem_ask_against_the_real_local_model(local_model, cli, mem_path, tmp_path):
    trace = tmp_path / "trace.json"
    before = len(served_requests(local_model))
    r = cli(
        "ask",
        "Where did I leave the magenta box?",
        "-m",
        str(mem_path),
        "--json",
        "--base-url",
        local_model.base_url,
        "--model",
        MODEL_NAME,
        "--provider",
        "llama.cpp",
        "--max-tool-calls",
        str(MAX_TOOL_CALLS),
        "--top-k",
        "3",
        "--trace",
        str(trace),
        env=SLOW,
    )
    assert "Traceback" not in r.stderr and "Traceback" not in r.stdout, r.stderr[-3000:]
    data = json.loads(r.stdout)
    t = json.loads(trace.read_text())
    # the loop ended within its budget
    assert data["cost"]["tool_calls"] <= MAX_TOOL_CALLS
    assert t["turns"] <= MAX_TOOL_CALLS + MAX_REASKS + 2 and t["reasks"] <= MAX_REASKS + 1
    # every tool call was run or rejected with a named reason
    assert t["tool_calls"], "the llama.cpp settings make the model search first"
    for call in t["tool_calls"]:
        assert call["ok"] or call["reason"], call
    # every request was valid for the server: 200, except pictures the text-only model refused
    refused = [e for e in t["events"] if "error" in e]
    assert all("image_url" in json.dumps(e["request"]) and "HTTP 500" in e["error"] for e in refused), refused
    assert len(refused) <= 1
    statuses = served_requests(local_model)[before:]
    assert len(statuses) == len(t["events"]) and statuses.count(500) == len(refused), statuses
    assert all(
        e["request"]["response_format"]["type"] == "json_object"
        for e in t["events"]
        if "tools" not in e["request"]
    )
    # the model saw no pictures, and the answer says so
    assert data["vision"] is False and any("saw no pictures" in n for n in data["notes"])
    assert data["model"] == MODEL_NAME
    # parsed, or a clear failure with a non-zero exit
    if r.returncode == 0:
        assert not data["failed"] and data["question_type"] in (
            "position",
            "time",
            "binary",
            "text",
            "duration",
        )
    else:
        assert r.returncode == 1
        lines = r.stderr.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith(("the question failed: ", "unsupported answer: ")), (
            lines
        )


def test_ravenmem_eval_split_against_the_real_local_model(local_model, cli, mem_path, tmp_path):
    queries = tmp_path / "queries.json"
    questions = [
        {
            "id": "box",
            "question": "Where did I leave the magenta box?",
            "type": "position",
            "answer": {"position": [7.0, 3.0, 0.5], "tolerance_m": 1.0},
        },
        {"id": "blue", "question": "Did I see a blue box?", "type": "binary", "answer": {"yes": True}},
    ]
    queries.write_text(json.dumps({"questions": questions}))
    before = len(served_requests(local_model))
    out = tmp_path / "run"
    r = cli(
        "eval",
        "--dataset",
        f"memory:{mem_path}",
        "--queries",
        str(queries),
        "--embedder",
        "test-color",
        "--method",
        "raven",
        "--vlm",
        MODEL_NAME,
        "--vlm-base-url",
        local_model.base_url,
        "--max-tool-calls",
        str(MAX_TOOL_CALLS),
        "--top-k",
        "3",
        "--workers",
        "1",
        "--cache-dir",
        str(tmp_path / "cache"),
        "--out",
        str(out),
        env={**SLOW, "RAVENMEM_VLM_PROVIDER": "llama.cpp", "RAVENMEM_VLM_VISION": "false"},
    )
    assert r.returncode == 0, (r.stdout[-2000:], r.stderr[-3000:])
    rows = [json.loads(line) for line in (out / "answers.jsonl").read_text().splitlines() if line.strip()]
    assert sorted(row["qid"] for row in rows) == ["blue", "box"]
    for row in rows:
        a = row["answer"]
        assert a["model"] == MODEL_NAME and a["vision"] is False and a["cost"]["images"] == 0
        assert a["cost"]["tool_calls"] <= MAX_TOOL_CALLS
        if a["failed"]:
            assert a["error"] and "\n" not in a["error"] and "Traceback" not in a["error"]
    statuses = served_requests(local_model)[before:]
    assert statuses and set(statuses) == {200}, statuses  # text from the start: every request taken
    summary = json.loads((out / "summary.json").read_text())
    assert summary  # the run was scored (no accuracy target)
    Path(out / "answers.jsonl").stat()
