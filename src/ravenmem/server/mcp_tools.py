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

from ..agent.base import METHODS
from ..agent.presets import PRESETS
from ..errors import RavenmemError
from ..memory.protocol import MAX_K, check_k
from ..runtime.images import decode_base64_image
from ..runtime.service import MAX_CALLS, Service
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
    return {
        "type": "object",
        "properties": {
            "question": {"type": "string", "minLength": 1, "maxLength": 2000, "description": "the question"},
            "method": {
                "type": "string",
                "enum": METHODS.names(),
                "description": f"how to answer (default {service.cfg.default_method})",
            },
            "preset": {
                "type": "string",
                "enum": sorted(PRESETS),
                "description": "the paper's settings for a benchmark (budget, k per tool, temperature)",
            },
            "top_k": {
                "anyOf": [
                    {"type": "integer", "minimum": 1, "maximum": MAX_K},
                    {
                        "type": "object",
                        "properties": {
                            t: {"type": "integer", "minimum": 1, "maximum": MAX_K}
                            for t in (*(x.key for x in TOOLS.values()), *TOOLS)
                        },
                        "additionalProperties": False,
                    },
                ],
                "description": "memories per tool call: N, or per tool {'text': 30, 'time': 200}",
            },
            "max_tool_calls": {
                "type": "integer",
                "minimum": 1,
                "maximum": MAX_CALLS,
                "description": "tool calls before the model must answer",
            },
            "navigate": {
                "type": "boolean",
                "description": "also plan a path on the memory's map to the answer (its goal: `navigation`)",
            },
            "allow_unsupported": {
                "type": "boolean",
                "description": "accept (and send to the robot) a position far from every memory the "
                "model was shown; without it such an answer is an error",
            },
        },
        "required": ["question"],
        "additionalProperties": False,
    }


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
    k = check_k(args.pop("k", 5))
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
    question = args.get("question")
    if not isinstance(question, str) or not question.strip() or len(question) > 2000:
        raise RavenmemError("ask: question must be a non-empty string of at most 2000 characters")
    known = {"question", "method", "preset", "top_k", "max_tool_calls", "navigate", "allow_unsupported"}
    extra = set(args) - known
    if extra:
        raise RavenmemError(f"ask: unknown argument(s) {', '.join(sorted(extra))}")
    for flag in ("navigate", "allow_unsupported"):
        if not isinstance(args.get(flag, False), bool):
            raise RavenmemError(f"ask: {flag} must be true or false")
    result = service.ask(
        question,
        method=args.get("method"),
        top_k=args.get("top_k"),
        max_tool_calls=args.get("max_tool_calls"),
        preset=args.get("preset"),
        navigate=args.get("navigate", False),
        allow_unsupported=args.get("allow_unsupported", False),
    )
    data = service.result_json(result, _url(base))
    service.publish_answer(data, drive=result.refusal is None)
    if result.refusal:
        return _error(result.refusal)
    recs = service.mem.get([e["id"] for e in data["evidence"]]) if data["evidence"] else []
    return _result(service, data, recs)


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
