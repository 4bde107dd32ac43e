"""`ravenmem ask` / `ravenmem caption` end to end: a memory on disk, a scripted VLM over HTTP."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
import typer
from typer.testing import CliRunner

import ravenmem
from ravenmem.cli.agent import register
from ravenmem.embed.base import EMBEDDERS
from ravenmem.types import Frame, Pose
from tests.agent.conftest import SCENE, T0
from tests.agent.scripted_server import answer, error, tool
from tests.conftest import ColorEmbedder, solid

EMBEDDERS.register("test-color")(lambda spec, **kw: ColorEmbedder())  # so `ravenmem.open` can rebuild it
REPO = Path(__file__).resolve().parents[2]


@pytest.fixture
def app() -> typer.Typer:
    a = typer.Typer()
    register(a)
    return a


@pytest.fixture
def mem_path(tmp_path) -> Path:
    p = tmp_path / "lab.mem"
    with ravenmem.create(p, embedder=ColorEmbedder(), ocr=False, thumb_size=32) as m:
        m.add_frames([Frame(image=solid(c), t=T0 + 10 * i, pose=Pose(x, y, 0.5, 0.1 * i), index=i)
                      for i, (c, x, y) in enumerate(SCENE)])  # fmt: skip
    return p


@pytest.fixture
def clean_env(monkeypatch, tmp_path):
    for var in ("RAVENMEM_VLM_MODEL", "RAVENMEM_VLM_BASE_URL", "RAVENMEM_VLM_API_KEY", "RAVENMEM_CONFIG"):
        monkeypatch.delenv(var, raising=False)
    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path / "xdg"))


def test_ask_offline_prints_the_answer_card(app, mem_path, clean_env):
    r = CliRunner().invoke(
        app, ["ask", "Where did I leave the magenta box?", "--memory", str(mem_path), "--offline"]
    )
    assert r.exit_code == 0, r.output
    out = r.output
    assert "type: position" in out and "method: offline" in out and "x y z yaw: 7.00 3.00 0.50" in out
    assert (
        "time seen: 2023-11-14T22:14:30" in out and "evidence memories" in out and "tool calls used: 0" in out
    )


def test_ask_without_vlm_config_says_it_used_the_offline_reasoner(app, mem_path, clean_env):
    r = CliRunner().invoke(app, ["ask", "Where is the magenta box?", "-m", str(mem_path), "--json"])
    assert r.exit_code == 0, r.output
    data = json.loads(r.stdout)
    assert data["method"] == "offline" and "no VLM configured" in data["note"]


def test_ask_json_with_a_vlm(app, mem_path, clean_env, server, tmp_path):
    ids = {r.frame_index: r.id for r in ravenmem.open(mem_path).all_records()}
    server.push(
        tool("search_text", query="magenta"),
        answer(question_type="position", evidence=[ids[7]], answer="There."),
    )
    trace = tmp_path / "trace.json"
    args = ["ask", "Where is the magenta box?", "-m", str(mem_path), "--json", "--base-url", server.base_url,
            "--model", "scripted-vlm", "--trace", str(trace), "--top-k", "3"]  # fmt: skip
    r = CliRunner().invoke(app, args)
    assert r.exit_code == 0, r.output
    data = json.loads(r.stdout)
    assert data["method"] == "raven" and data["text"] == "There." and data["position"] == [7.0, 3.0, 0.5]
    assert (
        data["cost"]["tool_calls"] == 1
        and data["cost"]["memories_shown"] == 3
        and data["cost"]["alpha"] == 0.25
    )
    assert data["cost"]["prompt_tokens"] > 0 and Path(data["evidence"][0]["image_file"]).exists()
    assert json.loads(trace.read_text())["events"] and server.requests[0]["model"] == "scripted-vlm"


def test_ask_env_config_and_failure_exit_code(app, mem_path, clean_env, server, monkeypatch):
    monkeypatch.setenv("RAVENMEM_VLM_BASE_URL", server.base_url)
    monkeypatch.setenv("RAVENMEM_VLM_MODEL", "env-model")
    server.default = error(503, "overloaded")
    r = CliRunner().invoke(app, ["ask", "Where is it?", "-m", str(mem_path), "--max-retries", "0"])
    assert r.exit_code == 1 and "FAILED" in r.output and "HTTP 503: overloaded" in r.output
    assert server.requests[0]["model"] == "env-model" and len(server.requests) == 1


def test_caption_command(app, mem_path, clean_env, server):
    server.default = {"content": "A coloured wall."}
    r = CliRunner().invoke(app, ["caption", "-m", str(mem_path), "--base-url", server.base_url, "--model", "cap",
                                 "--json"])  # fmt: skip
    # the default caption encoder is MiniLM, which is only loaded here if captions were written
    assert r.exit_code == 0, r.output
    assert json.loads(r.stdout)["captioned_now"] == 12


def test_errors_are_one_line_through_the_real_entry_point(tmp_path):
    env = {**os.environ, "PYTHONPATH": str(REPO / "src"), "XDG_CONFIG_HOME": str(tmp_path)}
    p = subprocess.run([sys.executable, "-m", "ravenmem.cli.main", "ask", "Where?", "-m", str(tmp_path / "none")],
                       capture_output=True, text=True, env=env, timeout=120)  # fmt: skip
    if "No such command 'ask'" in p.stderr + p.stdout:
        pytest.skip("the main CLI does not load cli/agent.py in this checkout")
    err = " ".join(p.stderr.split())  # rich wraps long lines when stderr is not a terminal
    assert p.returncode == 2 and err.startswith("error: memory") and "does not exist" in err
    assert "Traceback" not in p.stderr
