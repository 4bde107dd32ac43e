"""The latest mode through the service: HTTP routes and MCP tools are generated from the tools
table, so `latest` reaches them with its schema; the results carry each place's verdict."""

from __future__ import annotations

import asyncio
from contextlib import contextmanager
from typing import Any

import pytest

pytest.importorskip("fastapi", reason="the service needs the serve extra: pip install 'ravenmem[serve]'")
pytest.importorskip("mcp", reason="the service needs the serve extra: pip install 'ravenmem[serve]'")

from mcp import Client  # noqa: E402

import ravenmem  # noqa: E402
from tests.box_embedder import BoxEmbedder  # noqa: E402
from tests.robot.changes_world import World  # noqa: E402
from tests.server.conftest import serve_memory  # noqa: E402


def test_latest_over_http_and_mcp(world: World) -> None:
    reader = ravenmem.open(world.path, embedder=BoxEmbedder())  # the service closes it
    want = world.mem.last_seen("red box")
    with contextmanager(serve_memory)(reader, writable=False) as served:
        with served.client() as http:
            r = http.get("/search/text", params={"query": "red box", "latest": "true", "k": 3})
            assert r.status_code == 200, r.text
            rows = r.json()["results"]
            plain = http.get("/search/text", params={"query": "red box", "k": 3}).json()["results"]
        assert rows[0]["id"] == want.places[0].last.id and rows[0]["change"]["role"] == "sighting"
        assert {row["change"]["verdict"] for row in rows if row["change"]["role"] == "sighting"} >= {"moved"}
        assert all("change" not in row for row in plain)

        async def main(url: str) -> dict[str, Any]:
            async with Client(f"{url}/mcp", read_timeout_seconds=60) as client:
                tools = {t.name: t for t in (await client.list_tools()).tools}
                assert tools["search_text"].input_schema["properties"]["latest"]["type"] == "boolean"
                res = await client.call_tool("search_text", {"query": "red box", "latest": True, "k": 3})
                assert not res.is_error
                return dict(res.structured_content or {})

        data = asyncio.run(main(served.url))
        assert [row["id"] for row in data["results"]] == [row["id"] for row in rows]
        assert data["results"][0]["change"]["status"] == want.status
