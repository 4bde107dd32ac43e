"""Top-k means k: `diverse=false` returns exactly k memories, from every front end.

The text and image tools keep one hit per moment and place by default; `diverse` is one
argument of the tools table, so the agent's schema, the CLI flag `--diverse/--no-diverse`, the
HTTP query parameter and the MCP parameter all come from it. A memory of 10: a burst of 6 red
views of one moment and place, 2 more red views elsewhere, 2 blue ones. Asked for 8 red ones,
the diverse answer has the 5 different views (one of the burst), the other the 8 best, exactly 8.
"""

from __future__ import annotations

import json
import subprocess
import sys
from collections.abc import Iterator
from functools import partial
from pathlib import Path
from typing import Any

import anyio
import httpx
import pytest
from mcp import Client

import ravenmem
from ravenmem.agent.tool_calls import ToolRunner, WorkingMemory
from ravenmem.tools import TOOLS, TextArgs
from ravenmem.types import Frame, Pose
from tests.cli.helpers import REPO, assert_one_line_error, run_cli
from tests.conftest import ColorEmbedder, solid
from tests.server.conftest import running_service

T0 = 1_700_000_000.0
rm = partial(run_cli, unset=("RAVENMEM_SERVER", "RAVENMEM_TOKEN"))


def burst_frames() -> list[Frame]:
    frames = [Frame(solid("red"), T0 + 0.1 * i, Pose(1.0, 2.0), index=i) for i in range(6)]
    frames += [
        Frame(solid("red"), T0 + t, Pose(x, 0.0), index=10 + j) for j, (t, x) in enumerate(((30, 5), (60, 9)))
    ]
    frames += [Frame(solid("blue"), T0 + 90 + t, Pose(0.0, 5.0 * t), index=20 + t) for t in range(2)]
    return frames


@pytest.fixture(scope="module")
def burst(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("top-k") / "burst.mem"
    with ravenmem.create(path, embedder=ColorEmbedder(), ocr=False, thumb_size=16) as mem:
        mem.add_frames(burst_frames())
    return path


@pytest.fixture(scope="module")
def service(burst: Path) -> Iterator[str]:
    yield from running_service(burst, "--read-only")


def times(rows: list[dict[str, Any]]) -> list[float]:
    return sorted(round(r["t"] - T0, 1) for r in rows)


DENSE = 8  # the 8 red memories
BURST = [0.0, 0.1, 0.2, 0.3, 0.4, 0.5, 30.0, 60.0]
DIVERSE = [0.0, 30.0, 60.0, 90.0, 91.0]  # every different view there is: one of the burst


def test_the_tools_table_declares_diverse_once() -> None:
    field = TextArgs.model_fields["diverse"]
    assert field.default is True and "exactly k" in (field.description or "")
    for name in ("search_text", "search_image"):
        schema = TOOLS[name].json_schema()["properties"]["diverse"]
        assert schema["type"] == "boolean" and schema["description"] == field.description
        assert TOOLS[name].plain_schema()["properties"]["diverse"]["type"] == "boolean"
    assert "diverse" not in TOOLS["search_time"].json_schema()["properties"]


def test_the_agent_offers_diverse_and_gets_exactly_k(burst: Path) -> None:
    with ravenmem.open(burst, embedder=ColorEmbedder()) as mem:
        runner = ToolRunner(mem, top_k=DENSE, attach_images=False)
        specs = {s["function"]["name"]: s["function"]["parameters"] for s in runner.specs()}
        assert (
            specs["search_text"]["properties"]["diverse"]["description"]
            == TextArgs.model_fields["diverse"].description
        )
        dense = runner.run("search_text", {"query": "red", "diverse": False}, WorkingMemory())
        assert dense.ok and len(dense.hits) == DENSE and "diverse=False" in dense.text.splitlines()[0]
        div = runner.run("search_text", {"query": "red"}, WorkingMemory())
        assert sorted(round(h.memory.t - T0, 1) for h in div.hits) == DIVERSE


def test_cli_no_diverse_returns_exactly_k(burst: Path) -> None:
    # the real command, with the colour test embedder registered by name (tests/server/serve_color.py)
    def search(*args: str) -> subprocess.CompletedProcess[str]:
        cmd = [sys.executable, str(REPO / "tests" / "server" / "serve_color.py"), "search", "-m", str(burst)]
        return subprocess.run([*cmd, *args], capture_output=True, text=True, timeout=300)

    r = search("red", "-k", "8", "--no-diverse", "--json")
    assert r.returncode == 0, r.stderr
    assert times(json.loads(r.stdout)["results"]) == BURST
    r = search("red", "-k", "8", "--json")
    assert times(json.loads(r.stdout)["results"]) == DIVERSE
    r = search("--like", "1", "-k", "5", "--no-diverse", "--json")
    assert len(json.loads(r.stdout)["results"]) == 5  # more views like memory 1: 5 asked, 5 given
    err = assert_one_line_error(rm("search", "-m", str(burst), "--time", "+0s", "--no-diverse"))
    assert "--no-diverse applies to text and image searches only" in err


def test_http_and_cli_server_diverse_false_returns_exactly_k(service: str) -> None:
    with httpx.Client(base_url=service, timeout=30) as c:
        dense = c.get("/search/text", params={"q": "red", "k": DENSE, "diverse": "false"})
        assert dense.status_code == 200, dense.text
        assert times(dense.json()["results"]) == BURST
        assert times(c.get("/search/text", params={"q": "red", "k": DENSE}).json()["results"]) == DIVERSE
        like = c.get("/search/image", params={"memory_id": 1, "k": 5, "diverse": "false"}).json()
        assert len(like["results"]) == 5
        bad = c.get("/search/text", params={"q": "red", "diverse": "maybe"})
        assert bad.status_code == 422 and "diverse" in bad.json()["error"]
        openapi = c.get("/openapi.json").json()
        params = {p["name"] for p in openapi["paths"]["/search/text"]["get"]["parameters"]}
        assert "diverse" in params
    r = rm("search", "red", "--server", service, "-k", str(DENSE), "--no-diverse", "--json")
    assert r.returncode == 0, r.stderr
    assert times(json.loads(r.stdout)["results"]) == BURST


def test_mcp_diverse_false_returns_exactly_k(service: str) -> None:
    async def main() -> tuple[dict[str, Any], list[float], list[float]]:
        async with Client(f"{service}/mcp", read_timeout_seconds=60) as client:
            tools = {t.name: t for t in (await client.list_tools()).tools}
            dense = await client.call_tool("search_text", {"query": "red", "k": DENSE, "diverse": False})
            div = await client.call_tool("search_text", {"query": "red", "k": DENSE})
            assert not dense.is_error and not div.is_error
            return (
                tools["search_text"].input_schema["properties"]["diverse"],
                times(dense.structured_content["results"]),  # type: ignore[index]
                times(div.structured_content["results"]),  # type: ignore[index]
            )

    schema, dense, div = anyio.run(main)
    assert schema["type"] == "boolean" and schema["default"] is True
    assert dense == BURST and div == DIVERSE
