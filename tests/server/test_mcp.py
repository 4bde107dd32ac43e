"""The memory as MCP tools, through the `mcp` package's own client: stdio and streamable HTTP."""

from __future__ import annotations

import base64
import io
import json
import os
import sys
from pathlib import Path
from typing import Any

import anyio
import mcp_types as types
import pytest
from mcp import Client
from mcp.client.stdio import StdioServerParameters
from mcp.client.streamable_http import streamable_http_client
from mcp.shared._httpx_utils import create_mcp_http_client
from mcp.shared.exceptions import MCPError
from PIL import Image

from ravenmem.server.mcp_tools import tool_schema
from ravenmem.tools import TOOLS
from tests.server.conftest import TOKEN, Served, make_memory

REPO = Path(__file__).resolve().parents[2]
NAMES = ["search_text", "search_image", "search_time", "search_position", "ask"]


async def exercise(client: Client, image_base: str | None) -> dict[str, Any]:
    """List the tools, check their schemas, call each one; returns what was seen."""
    listed = (await client.list_tools()).tools
    by_name = {t.name: t for t in listed}
    assert list(by_name) == NAMES
    for name, t in TOOLS.items():
        schema = by_name[name].input_schema
        assert schema == tool_schema(t)
        assert set(schema["properties"]) >= set(t.args.model_fields) | {"k"}
        assert schema["properties"]["k"]["maximum"] == 1000
        assert by_name[name].description == t.description()
    assert by_name["search_text"].input_schema["required"] == ["query"]
    assert by_name["ask"].input_schema["required"] == ["question"]

    seen: dict[str, Any] = {}
    text = await client.call_tool("search_text", {"query": "red", "k": 2})
    assert not text.is_error
    data = json.loads(text.content[0].text)  # type: ignore[union-attr]
    assert data == text.structured_content and data["tool"] == "search_text"
    assert {r["id"] for r in data["results"]} == {2, 9}
    assert [r["supported"] for r in data["results"]] == [True, True]  # the verdict `ask` declines by
    pictures = [c for c in text.content if isinstance(c, types.ImageContent)]
    assert len(pictures) == 2 and all(p.mime_type == "image/jpeg" for p in pictures)
    arr = Image.open(io.BytesIO(base64.b64decode(pictures[0].data))).convert("RGB")
    r, g, _ = arr.getpixel((5, 5))
    assert r > 200 and g < 60  # the red memory's picture
    want = f"{image_base}/memories/{data['results'][0]['id']}/image" if image_base else None
    assert data["results"][0]["image"] == want

    like = await client.call_tool("search_image", {"memory_id": 4, "k": 2})
    assert {r["id"] for r in like.structured_content["results"]} == {7, 11}  # type: ignore[index]
    buf = io.BytesIO()
    Image.new("RGB", (20, 20), (255, 255, 0)).save(buf, "PNG")
    pic = await client.call_tool("search_image", {"image": base64.b64encode(buf.getvalue()).decode(), "k": 1})
    assert pic.structured_content["results"][0]["id"] == 3  # type: ignore[index]
    when = await client.call_tool("search_time", {"time": "+20s", "k": 3})
    assert [r["offset_s"] for r in when.structured_content["results"]] == [20.0, 30.0, 40.0]  # type: ignore[index]
    where = await client.call_tool("search_position", {"x": 3, "y": 1, "k": 1})
    assert where.structured_content["results"][0]["id"] == 4  # type: ignore[index]
    ans = await client.call_tool("ask", {"question": "where is the yellow thing?", "method": "embedder-only"})
    assert not ans.is_error
    a = ans.structured_content
    assert a["found"] and a["position"][:2] == [2.0, 0.0] and a["evidence"][0]["id"] == 3  # type: ignore[index]
    assert any(isinstance(c, types.ImageContent) for c in ans.content)
    # ask takes what /ask and `ravenmem ask` take: per-tool k and the tool-call budget
    props = by_name["ask"].input_schema["properties"]
    assert props["max_tool_calls"]["maximum"] == 20
    assert {"integer", "object"} == {s["type"] for s in props["top_k"]["anyOf"]}
    per_tool = {"question": "where is the yellow thing?", "method": "offline", "top_k": {"text": 2}}
    fine = await client.call_tool("ask", {**per_tool, "max_tool_calls": 2})
    assert not fine.is_error and fine.structured_content["found"]  # type: ignore[index]
    bad = await client.call_tool("ask", {**per_tool, "max_tool_calls": 99})
    assert bad.is_error and "max_tool_calls" in bad.content[0].text  # type: ignore[union-attr]

    bad = await client.call_tool("search_text", {"query": "red", "k": 5000})
    assert bad.is_error and "k must be from 1 to 1000" in bad.content[0].text  # type: ignore[union-attr]
    bad = await client.call_tool("search_position", {"x": 1})
    assert bad.is_error and "y" in bad.content[0].text and "\n" not in bad.content[0].text  # type: ignore[union-attr]
    bad = await client.call_tool("search_smell", {})
    assert bad.is_error and "unknown tool" in bad.content[0].text  # type: ignore[union-attr]
    seen["ok"] = True
    return seen


def test_mcp_over_stdio(tmp_path):
    path = tmp_path / "scene.mem"
    make_memory(path).close()
    env = dict(os.environ, PYTHONPATH=f"{REPO / 'src'}{os.pathsep}{REPO}")
    params = StdioServerParameters(
        command=sys.executable,
        args=[str(REPO / "tests" / "server" / "serve_color.py"), "mcp", "--memory", str(path)],
        env=env,
    )

    async def main() -> dict[str, Any]:
        async with Client(params, read_timeout_seconds=60) as client:
            return await exercise(client, None)

    assert anyio.run(main) == {"ok": True}


def test_mcp_over_streamable_http(served: Served):
    async def main() -> dict[str, Any]:
        async with Client(f"{served.url}/mcp", read_timeout_seconds=60) as client:
            return await exercise(client, served.url)

    assert anyio.run(main) == {"ok": True}


def test_mcp_over_http_needs_the_token(served_token: Served):
    async def main(token: str | None) -> dict[str, Any]:
        headers = {"Authorization": f"Bearer {token}"} if token else None
        http = create_mcp_http_client(headers=headers)
        async with (
            http,
            Client(streamable_http_client(f"{served_token.url}/mcp", http_client=http)) as client,
        ):
            return await exercise(client, served_token.url)

    assert anyio.run(main, TOKEN) == {"ok": True}
    with pytest.raises(Exception) as refused:  # noqa: B017 - an exception group (3.11+) or the error
        anyio.run(main, None)
    assert any(isinstance(e, MCPError) for e in leaves(refused.value))  # the client saw the 401


def leaves(e: BaseException) -> list[BaseException]:
    subs = getattr(e, "exceptions", None)  # an exception group
    if subs is not None:
        return [x for sub in subs for x in leaves(sub)]
    return [e]
