"""The VLM client against a real HTTP server: retries, backoff, timeouts, tool rejection, config."""

from __future__ import annotations

import json
import time

import numpy as np
import pytest

from ravenmem.agent import client as client_module
from ravenmem.agent.client import ToolsRejectedError, VLMClient, VLMError, image_data_url, redact_images
from ravenmem.agent.config import VLMConfig
from ravenmem.errors import InputError
from tests.agent.conftest import config_for
from tests.agent.scripted_server import ScriptedModel, content, error, tool

MSG = [{"role": "user", "content": "hi"}]


def test_plain_reply_usage_and_headers(server, client):
    server.push(content("hello"))
    r = client.chat(MSG)
    assert r.content == "hello" and r.tool_calls == [] and r.finish_reason == "stop"
    assert r.prompt_tokens > 0 and r.completion_tokens > 0
    body = server.requests[0]
    assert body["model"] == "scripted-vlm" and body["messages"] == MSG and "tools" not in body
    assert server.headers[0]["authorization"] == "Bearer test-key"


def test_tool_calls_are_parsed(server, client):
    server.push(tool("search_text", query="red"))
    spec = [{"type": "function", "function": {"name": "search_text", "parameters": {"type": "object"}}}]
    r = client.chat(MSG, tools=spec, tool_choice="auto")
    assert [c.name for c in r.tool_calls] == ["search_text"]
    assert json.loads(r.tool_calls[0].arguments) == {"query": "red"}
    assert server.requests[0]["tools"] == spec and server.requests[0]["tool_choice"] == "auto"


@pytest.mark.parametrize("status", [500, 502, 503, 429])
def test_transient_errors_are_retried_then_succeed(server, client, status):
    server.push(error(status), error(status), content("ok"))
    r = client.chat(MSG)
    assert r.content == "ok"
    assert len(server.requests) == 3 and client.retries == 2 and client.requests == 3
    assert [e.get("error", "").startswith(f"HTTP {status}") for e in client.events] == [True, True, False]


def test_retries_are_bounded_with_exponential_backoff(server):
    waits: list[float] = []
    c = VLMClient(config_for(server, max_retries=3, backoff=0.5, backoff_max=1.5), sleep=waits.append)
    server.default = error(503, "overloaded")
    with pytest.raises(VLMError, match=r"failed after 4 attempt\(s\): HTTP 503: overloaded"):
        c.chat(MSG)
    assert len(server.requests) == 4
    assert waits == [0.5, 1.0, 1.5]  # 0.5 * 2**n, capped


def test_retry_after_header_is_honoured_up_to_the_cap(server):
    waits: list[float] = []
    c = VLMClient(config_for(server, backoff=0.01, backoff_max=5.0), sleep=waits.append)
    server.push(error(429, "slow down", headers={"Retry-After": "2"}), content("ok"))
    assert c.chat(MSG).content == "ok"
    assert waits == [2.0]


def test_timeouts_are_retried_then_fail_clearly(server):
    c = VLMClient(config_for(server, timeout=0.3, max_retries=1))
    server.push({"content": "late", "delay": 1.0}, {"content": "on time"})
    assert c.chat(MSG).content == "on time"
    assert c.retries == 1
    server.push({"content": "late", "delay": 1.0}, {"content": "late", "delay": 1.0})
    with pytest.raises(VLMError, match="timed out after 0.3 s"):
        c.chat(MSG)


def test_client_errors_are_not_retried(server, client):
    server.push(error(401, "bad key"))
    with pytest.raises(VLMError, match="refused the request: HTTP 401: bad key"):
        client.chat(MSG)
    assert len(server.requests) == 1


def test_rejected_tools_raise_a_distinct_error(server, client):
    server.reject_tools = True
    spec = [{"type": "function", "function": {"name": "f", "parameters": {"type": "object"}}}]
    with pytest.raises(ToolsRejectedError, match="does not support tools"):
        client.chat(MSG, tools=spec)
    assert len(server.requests) == 1


def test_broken_json_body_is_a_clear_failure(server, client):
    server.default = {"raw": "this is not json"}
    with pytest.raises(VLMError):
        client.chat(MSG)


def test_unreachable_endpoint_fails_after_retries():
    with ScriptedModel() as srv:
        url = srv.base_url
    c = VLMClient(VLMConfig(base_url=url, model="m", timeout=1.0, max_retries=1, backoff=0.0))
    with pytest.raises(VLMError, match="connection failed"):
        c.chat(MSG)
    assert c.requests == 2


def test_no_model_configured_is_an_error():
    with pytest.raises(InputError, match="no VLM model configured: pass --model"):
        VLMClient(VLMConfig())


def test_images_are_data_urls_and_redacted_in_traces(tmp_path):
    img = np.zeros((20, 30, 3), np.uint8)
    img[:, :, 0] = 200
    url = image_data_url(img)
    assert url.startswith("data:image/jpeg;base64,")
    p = tmp_path / "a.jpg"
    from PIL import Image

    Image.fromarray(img).save(p)
    assert (
        image_data_url(p)
        == "data:image/jpeg;base64," + __import__("base64").b64encode(p.read_bytes()).decode()
    )
    (tmp_path / "notes.jpg").write_text("not a picture")
    with pytest.raises(InputError, match="not an image"):
        image_data_url(tmp_path / "notes.jpg")
    msgs = [{"role": "user", "content": [{"type": "image_url", "image_url": {"url": url}}]}]
    red = redact_images(msgs)
    text = json.dumps(red)
    assert "base64" not in text and "image/jpeg" in text and "sha1:" in text
    assert msgs[0]["content"][0]["image_url"]["url"] == url  # the original is untouched


# ------------------------------------------------------------------ configuration
def test_config_precedence_flags_env_file(tmp_path):
    f = tmp_path / "config.toml"
    f.write_text(
        '[vlm]\nbase_url = "http://file/v1"\nmodel = "file-model"\ntimeout = 7\ntool_mode = "json"\n'
    )
    env = {"RAVENMEM_VLM_MODEL": "env-model", "OPENAI_API_KEY": "sk-env"}
    cfg = VLMConfig.resolve(config_path=f, env=env, timeout=None, base_url="http://flag/v1")
    assert (cfg.base_url, cfg.model, cfg.api_key, cfg.timeout, cfg.tool_mode) == (
        "http://flag/v1",
        "env-model",
        "sk-env",
        7.0,
        "json",
    )
    assert cfg.public()["api_key"] == "***"
    env2 = {"RAVENMEM_CONFIG": str(f), "RAVENMEM_VLM_API_KEY": "rk", "OPENAI_API_KEY": "sk"}
    assert VLMConfig.resolve(env=env2).api_key == "rk"
    assert VLMConfig.resolve(env=env2).model == "file-model"


def test_default_config_file_location(tmp_path):
    d = tmp_path / "ravenmem"
    d.mkdir()
    (d / "config.toml").write_text('[vlm]\nmodel = "xdg-model"\n')
    assert VLMConfig.resolve(env={"XDG_CONFIG_HOME": str(tmp_path)}).model == "xdg-model"
    assert not VLMConfig.resolve(env={"XDG_CONFIG_HOME": str(tmp_path / "none")}).configured


@pytest.mark.parametrize(
    "text, match",
    [
        ('[vlm]\nmodle = "x"\n', "unknown key"),
        ('[vlm]\ntimeout = "soon"\n', "timeout"),
        ("[vlm\n", "not valid TOML"),
        ('[vlm]\ntool_mode = "magic"\n', "tool_mode"),
    ],
)
def test_bad_config_files_name_the_problem(tmp_path, text, match):
    f = tmp_path / "c.toml"
    f.write_text(text)
    with pytest.raises(InputError, match=match):
        VLMConfig.resolve(config_path=f, env={})


def test_bad_env_value_is_an_input_error():
    with pytest.raises(InputError, match="max_retries"):
        VLMConfig.resolve(env={"RAVENMEM_VLM_MAX_RETRIES": "many"})


# ------------------------------------------------------------------ wall-clock limits
def wait_for(cond, seconds: float = 5.0) -> bool:
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        if cond():
            return True
        time.sleep(0.05)
    return cond()


def test_a_dripping_server_is_cut_off_at_the_request_limit(server):
    """One byte every 0.5 s never trips a per-read timeout; the total limit per attempt does."""
    server.default = {"content": "never finishes", "drip": 0.5}
    c = VLMClient(config_for(server, timeout=1.5, max_retries=1))
    t0 = time.monotonic()
    with pytest.raises(VLMError, match=r"failed after 2 attempt\(s\): timed out after 1.5 s"):
        c.chat(MSG)
    took = time.monotonic() - t0
    assert took >= 3.0, (
        took
    )  # each attempt ran to its 1.5 s limit (the drip never ends: no upper bound to race)
    assert len(server.requests) == 2
    assert wait_for(lambda: server.drips_abandoned == 2)  # both connections were really closed
    server.default = content("fine again")
    assert c.chat(MSG).content == "fine again"  # the client recovers after abandoning a request


def test_the_callers_deadline_cuts_attempts_and_waits(server):
    server.default = {"content": "never finishes", "drip": 0.5}
    c = VLMClient(config_for(server, timeout=30, max_retries=5))
    with pytest.raises(VLMError, match=r"out of time for this question \(last error: timed out after 1.2 s"):
        c.chat(MSG, deadline=time.monotonic() + 1.2)
    assert len(server.requests) == 1  # no second attempt after the caller's deadline
    waits: list[float] = []
    c = VLMClient(config_for(server, backoff=5.0, backoff_max=5.0, max_retries=3), sleep=waits.append)
    server.default = error(503, "busy")
    with pytest.raises(VLMError, match="out of time for this question"):
        c.chat(MSG, deadline=time.monotonic() + 2.0)
    assert waits == []  # a 5 s wait past a 2 s deadline is not slept


def test_temperature_and_seed_are_sent(server):
    c = VLMClient(config_for(server, temperature=0.2, seed=7))
    server.push(content("a"), content("b"))
    c.chat(MSG)
    c.chat(MSG, temperature=0.0, seed=3)
    assert [(r["temperature"], r["seed"]) for r in server.requests] == [(0.2, 7), (0.0, 3)]


def test_an_oversized_reply_is_refused_before_it_is_read(server, monkeypatch):
    monkeypatch.setattr(client_module, "MAX_REPLY_BYTES", 64)
    server.default = content("x" * 500)
    with pytest.raises(VLMError, match="over the 64-byte limit"):
        VLMClient(config_for(server, max_retries=0)).chat(MSG)


@pytest.mark.parametrize("field, value", [("timeout", 0), ("question_timeout", -1), ("temperature", 3.0)])
def test_bad_limits_are_input_errors(field, value):
    with pytest.raises(InputError, match=field):
        VLMConfig(model="m", **{field: value})
