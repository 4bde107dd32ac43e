"""`ravenmem ask` / `ravenmem caption` as users run them: the real command in a subprocess, a
memory on disk, a scripted VLM over HTTP (the one-line refusals forked by one driver:
`forked_plugin_cli`)."""

from __future__ import annotations

import json
import time

import pytest

import ravenmem
from tests.agent.conftest import REPO, run_cli
from tests.agent.scripted_server import answer, error, tool


@pytest.fixture
def cli(color_plugin, tmp_path):
    home = tmp_path / "home"
    return lambda *args, **kw: run_cli(*args, site=color_plugin, home=home, **kw)


def ids_of(mem_path) -> dict[int, int]:
    with ravenmem.open(mem_path) as m:
        return {r.frame_index: r.id for r in m.all_records()}


def test_ask_offline_prints_the_answer_card(cli, mem_path):
    r = cli("ask", "Where did I leave the magenta box?", "--memory", str(mem_path), "--offline")
    assert r.returncode == 0, r.stderr
    out = r.stdout
    assert "type: position" in out and "method: offline" in out and "x y z yaw: 7.00 3.00 0.50 40 deg" in out
    assert "position from evidence, yaw from evidence" in out and "embedder test-color" in out
    assert (
        "time seen: 2023-11-14T22:14:30" in out and "evidence memories" in out and "tool calls used: 0" in out
    )
    assert "yaw deg" in out  # the evidence table names its unit, as search does


@pytest.mark.parametrize("method", ["raven", "vlm-only", "caption"])
def test_vlm_methods_without_a_model_fail_with_one_line(forked_plugin_cli, mem_path, method):
    r = forked_plugin_cli("ask", "Where is the magenta box?", "-m", str(mem_path), "--method", method)
    err = r.stderr.strip()
    assert r.returncode == 2 and r.stdout == "" and "Traceback" not in r.stderr
    assert len(err.splitlines()) == 1, err
    assert err.startswith(f"error: method '{method}' needs a VLM: no VLM model configured")
    assert "--model" in err and "RAVENMEM_VLM_MODEL" in err and "--offline" in err


def test_caption_without_a_model_fails_with_one_line(forked_plugin_cli, mem_path):
    r = forked_plugin_cli("caption", "-m", str(mem_path))
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1 and "needs a VLM" in r.stderr


def test_ask_json_with_a_vlm_preset_top_k_temperature_and_seed(cli, mem_path, server, tmp_path):
    ids = ids_of(mem_path)
    server.push(
        tool("search_time", time="+70"),
        answer(question_type="position", evidence=[ids[7]], answer="There.", yaw_deg=-90),
    )
    trace = tmp_path / "trace.json"
    r = cli(
        "ask",
        "Where is the magenta box?",
        "-m",
        str(mem_path),
        "--json",
        "--base-url",
        server.base_url,
        "--model",
        "scripted-vlm",
        "--trace",
        str(trace),
        "--preset",
        "findingdory",
        "--top-k",
        "time=3,text=2",
        "--temperature",
        "0.7",
        "--seed",
        "42",
    )
    assert r.returncode == 0, r.stderr
    data = json.loads(r.stdout)
    assert data["method"] == "raven" and data["text"] == "There." and data["position"] == [7.0, 3.0, 0.5]
    assert data["yaw"] == pytest.approx(-1.5707963) and data["yaw_source"] == "model"
    # only the time tool ran: no embedder took part, and none was loaded to name it
    assert (data["model"], data["preset"], data["embedder"]) == ("scripted-vlm", "findingdory", None)
    assert data["model_host"] == server.base_url.split("/")[2] and "test-key" not in r.stdout
    assert data["cost"]["tool_calls"] == 1 and data["cost"]["memories_shown"] == 3
    assert data["cost"]["alpha"] == 0.25 and data["cost"]["image_bytes"] > 0
    assert any("no position given" in n for n in data["notes"])
    body = server.requests[0]
    assert (body["model"], body["temperature"], body["seed"]) == ("scripted-vlm", 0.7, 42)
    ks = {t["function"]["name"]: t["function"]["description"] for t in body["tools"]}
    assert "up to 3 memories" in ks["search_time"] and "up to 2 memories" in ks["search_text"]
    assert "up to 1 memories" in ks["search_position"] and "at most 15 tool calls" in server.texts(0)
    assert json.loads(trace.read_text())["events"]


def test_a_dripping_model_fails_the_question_within_its_time_limit(cli, mem_path, server):
    """One byte a second never trips a per-read timeout: only the 2 s limit on the whole reply
    ends the question. Asserted by what happened, not by the machine's speed: the client hung up
    on the reply (the server saw it), once, and the command ended long before the reply could
    have finished dripping."""
    server.default = {"content": "{}", "drip": 1.0}
    t0 = time.monotonic()
    r = cli(
        "ask",
        "Where is it?",
        "-m",
        str(mem_path),
        "--json",
        "--base-url",
        server.base_url,
        "--model",
        "m",
        "--timeout",
        "2",
        "--max-retries",
        "0",
    )
    took = time.monotonic() - t0
    data = json.loads(r.stdout)
    assert data["failed"] is True and "timed out after 2 s (no complete reply" in data["error"]
    assert r.returncode == 1 and len(server.requests) == 1  # --max-retries 0: one attempt
    # the reply is hundreds of bytes at one a second: it was cut off, not waited for
    reply_s = len(json.dumps(server.responses[0])) * 1.0
    assert reply_s > 100 and took < reply_s / 2, (reply_s, took)
    deadline = time.monotonic() + 30
    while server.drips_abandoned < 1 and time.monotonic() < deadline:
        time.sleep(0.05)
    assert server.drips_abandoned == 1  # the client closed the connection mid-reply


def test_a_failed_ask_is_rendered_and_exits_1(cli, mem_path, server):
    server.default = error(503, "overloaded")
    r = cli(
        "ask",
        "Where is it?",
        "-m",
        str(mem_path),
        "--max-retries",
        "0",
        env={"RAVENMEM_VLM_BASE_URL": server.base_url, "RAVENMEM_VLM_MODEL": "env-model"},
    )
    assert "FAILED" in r.stdout and "HTTP 503: overloaded" in r.stdout
    assert server.requests[0]["model"] == "env-model" and len(server.requests) == 1
    assert r.returncode == 1


def test_caption_command(cli, mem_path, server, monkeypatch):
    server.default = {"content": "A coloured wall."}
    r = cli(
        "caption",
        "-m",
        str(mem_path),
        "--base-url",
        server.base_url,
        "--model",
        "cap",
        "--json",
        "--segment-frames",
        "4",
    )
    assert r.returncode == 0, r.stderr
    out = json.loads(r.stdout)
    assert (out["captioned_now"], out["segment_frames"], out["memories"]) == (3, 4, 12)
    assert [
        sum(1 for p in q["messages"][0]["content"] if p["type"] == "image_url") for q in server.requests
    ] == [4] * 3


def test_bad_flags_are_one_line_errors(forked_plugin_cli, mem_path):
    for args, msg in (
        (["--preset", "dory"], "unknown preset 'dory'"),
        (["--top-k", "time=lots", "--offline"], "--top-k"),
        (
            [
                "--method",
                "raven",
                "--base-url",
                "http://127.0.0.1:9/v1",
                "--model",
                "m",
                "--top-k",
                "colour=3",
            ],
            "unknown tool 'colour'",
        ),
        (
            [
                "--method",
                "raven",
                "--base-url",
                "http://127.0.0.1:9/v1",
                "--model",
                "m",
                "--time-mode",
                "back",
            ],
            "time_mode",
        ),
    ):
        r = forked_plugin_cli("ask", "Where?", "-m", str(mem_path), *args)
        assert r.returncode == 2 and msg in r.stderr and "Traceback" not in r.stderr, (args, r.stderr)


def test_errors_are_one_line_through_the_real_entry_point(cli, tmp_path):
    r = cli("ask", "Where?", "-m", str(tmp_path / "none"), "--offline")
    err = " ".join(r.stderr.split())  # rich wraps long lines when stderr is not a terminal
    assert r.returncode == 2 and err.startswith("error: memory") and "does not exist" in err
    assert "Traceback" not in r.stderr and REPO.exists()
