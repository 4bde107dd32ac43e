"""The memory as MCP tools: the four retrieval tools and `ask`, for any MCP client.

The tools, their descriptions and their input schemas come from `ravenmem.tools.TOOLS` (plus
`k`), so an argument added there appears here unchanged. A call returns the hits as JSON (the
`--json` shape of the CLI, also as structured content) followed by each hit's picture as MCP
image content, so a model can look at what the robot saw. Served over stdio
(`ravenmem mcp --memory DIR`) and streamable HTTP (`/mcp` on `ravenmem serve`).
"""

from __future__ import annotations

import base64
import json
import logging
from typing import Any

import anyio
import mcp_types as types
from mcp.server.lowlevel import Server

from ..errors import RavenmemError
from ..memory.protocol import MAX_K
from ..runtime.ask import AskArgs, input_schema
from ..runtime.images import decode_base64_image
from ..runtime.service import Service
from ..tools import TOOLS, Tool
from ..types import MemoryRecord

log = logging.getLogger(__name__)

MAX_IMAGES = 8  # pictures attached per call (the first hits); the JSON lists every hit
MIME = {".jpg": "image/jpeg", ".jpeg": "image/jpeg", ".png": "image/png"}
K_SCHEMA = {
    "type": "integer",
    "minimum": 1,
    "maximum": MAX_K,
    "default": 5,
    "description": f"how many memories to return (1 to {MAX_K})",
}
IMAGE_SCHEMA = {
    "type": "string",
    "description": "a query picture, base64 JPEG or PNG (or a data: URL); instead of memory_id",
}


def tool_schema(tool: Tool) -> dict[str, Any]:
    """The tool's argument model as JSON schema, plus `k` (and a picture for the image tool)."""
    schema = dict(tool.json_schema())
    props = dict(schema.get("properties", {}))
    props["k"] = K_SCHEMA
    if tool.name == "search_image":
        props["image"] = IMAGE_SCHEMA
    schema["properties"] = props
    return schema


def ask_schema(service: Service) -> dict[str, Any]:
    """The `ask` tool's input: `AskArgs` (the one request of every front end) as JSON schema."""
    schema = input_schema()
    schema["properties"]["method"]["description"] += f" (default {service.cfg.default_method})"
    return schema


def build_server(service: Service) -> Server[Any]:
    """An MCP server (low-level API: the schemas are ours, not inferred from signatures)."""

    async def list_tools(ctx: Any, params: Any) -> types.ListToolsResult:
        tools = [
            types.Tool(name=t.name, description=t.description(), input_schema=tool_schema(t))
            for t in TOOLS.values()
        ]
        tools.append(
            types.Tool(
                name="ask",
                description="Answer a question about what the robot saw (where, when, yes/no, how long), "
                "with the evidence memories and their pictures.",
                input_schema=ask_schema(service),
            )
        )
        return types.ListToolsResult(tools=tools)

    async def call_tool(ctx: Any, params: types.CallToolRequestParams) -> types.CallToolResult:
        args = dict(params.arguments or {})
        base = _base_url(ctx)
        try:
            if params.name == "ask":
                return await anyio.to_thread.run_sync(lambda: _ask(service, args, base))
            tool = TOOLS.get(params.name)
            if tool is None:
                raise RavenmemError(f"unknown tool {params.name!r}; choose one of: {', '.join(TOOLS)}, ask")
            return await anyio.to_thread.run_sync(lambda: _search(service, tool, args, base))
        except RavenmemError as e:
            return _error(str(e))
        except Exception:
            log.exception("MCP tool %s failed", params.name)
            return _error("internal error; the service log has the details")

    return Server("ravenmem", version="0.1.0", on_list_tools=list_tools, on_call_tool=call_tool)


def _base_url(ctx: Any) -> str | None:
    """The HTTP origin the call came through (None over stdio, where no image URL exists)."""
    request = getattr(ctx, "request", None)
    url = getattr(request, "base_url", None)
    return str(url).rstrip("/") if url is not None else None


def _search(service: Service, tool: Tool, args: dict[str, Any], base: str | None) -> types.CallToolResult:
    k = args.pop("k", 5)  # checked once, where the tool runs (`Tool.run`)
    picture = args.pop("image", None) if tool.name == "search_image" else None
    image = None
    if picture is not None:
        if not isinstance(picture, str):
            raise RavenmemError("image must be a base64 string")
        image = decode_base64_image(picture, service.cfg.max_pixels, "image", service.gate)
    call = tool.validate(args)
    hits = service.search(tool, call, k, image=image)
    rows = service.rows(hits, _url(base))
    data = {"mode": tool.key, "tool": tool.name, "results": rows}
    return _result(service, data, [h.memory for h in hits])


def _ask(service: Service, args: dict[str, Any], base: str | None) -> types.CallToolResult:
    result = service.ask(AskArgs.check(args))
    data = service.result_json(result, _url(base))
    if result.refusal:
        return _error(result.refusal)
    return _result(service, data, service.mem.stored([e.id for e in result.evidence]))


def _url(base: str | None) -> Any:
    def image_url(rec: MemoryRecord) -> str | None:
        return f"{base}/memories/{rec.id}/image" if base else None

    return image_url


def _result(service: Service, data: dict[str, Any], recs: list[MemoryRecord]) -> types.CallToolResult:
    content: list[Any] = [types.TextContent(text=json.dumps(data))]
    for rec in recs[:MAX_IMAGES]:
        p = service.image_file(rec)
        mime = MIME.get(p.suffix.lower()) if p is not None else None
        if p is None or mime is None:
            continue
        content.append(types.TextContent(text=f"memory {rec.id}:"))
        content.append(types.ImageContent(data=base64.b64encode(p.read_bytes()).decode(), mime_type=mime))
    return types.CallToolResult(content=content, structured_content=data)


def _error(message: str) -> types.CallToolResult:
    return types.CallToolResult(content=[types.TextContent(text=" ".join(message.split()))], is_error=True)


async def run_stdio(service: Service) -> None:
    """Serve MCP over this process's stdin/stdout until the client closes it."""
    from mcp.server.stdio import stdio_server

    server = build_server(service)
    async with stdio_server() as (read, write):
        await server.run(read, write, server.create_initialization_options())
