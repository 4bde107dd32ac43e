"""The search routes, generated from `ravenmem.tools.TOOLS`.

Each tool's argument model plus `k` is its route's query model: an argument added to a tool
appears in HTTP, checked and documented in `/openapi.json`, without editing this file. `q` and
`t` are accepted for `query` and `time`; list arguments (`near`) as `1,2,3` or repeated.
"""

# no `from __future__ import annotations` here: FastAPI reads the generated query models from
# the route functions' annotations at run time.
from collections.abc import Awaitable, Callable
from typing import Annotated, Any, get_args, get_origin

from fastapi import FastAPI, File, Query, Request, UploadFile
from pydantic import BaseModel, Field, create_model, model_validator
from starlette.concurrency import run_in_threadpool

from ..errors import InputError
from ..memory.protocol import MAX_K
from ..runtime.images import DecodeGate, decode_image
from ..runtime.service import Service
from ..tools import TOOLS, Tool, ToolArgs
from ..types import MemoryRecord

SHORT_NAMES = {"q": "query", "t": "time"}  # short query names some clients prefer
Blocking = Callable[[Callable[[], Any]], Awaitable[Any]]
UrlFor = Callable[[Request], Callable[[MemoryRecord], str | None]]


def add_search_routes(
    app: FastAPI, service: Service, blocking: Blocking, image_url_for: UrlFor, gate: DecodeGate | None = None
) -> None:
    """`GET /search/{key}` for every tool, and `POST /search/image` with an uploaded picture
    (decoded within `gate`, the service's bound on pictures in RAM)."""
    for tool in TOOLS.values():
        _search_route(app, tool, service, blocking, image_url_for)
    _image_upload_route(app, service, blocking, image_url_for, gate)


class _Short(BaseModel):
    """Query-string conveniences: `q`/`t` for `query`/`time`; lists as `1,2,3` or repeated."""

    @model_validator(mode="before")
    @classmethod
    def _query_string(cls, data: Any) -> Any:
        if not isinstance(data, dict):
            return data
        data = dict(data)
        fields = cls.model_fields
        for short, full in SHORT_NAMES.items():
            if short in data and full in fields and short not in fields:
                data.setdefault(full, data.pop(short))
        for name, f in fields.items():
            v = data.get(name)
            if _is_list(f.annotation) and isinstance(v, list) and all(isinstance(s, str) for s in v):
                data[name] = [p for s in v for p in s.split(",") if p.strip()]
        return data


def _is_list(annotation: Any) -> bool:
    """`list[float]`, `list[float] | None`, ...: an argument given as several values."""
    return get_origin(annotation) is list or any(_is_list(a) for a in get_args(annotation))


def query_model(tool: Tool) -> type[BaseModel]:
    """The tool's argument model plus `k`, read from the query string."""
    fields: dict[str, Any] = {
        "k": (int, Field(5, ge=1, le=MAX_K, description=f"how many results (1 to {MAX_K})")),
    }
    return create_model(  # type: ignore[call-overload, no-any-return]
        f"{tool.name}_query", __base__=(tool.args, _Short), __doc__=tool.summary, **fields
    )


def _split(model: BaseModel, tool: Tool) -> tuple[ToolArgs, int]:
    data = model.model_dump()
    k = int(data.pop("k"))
    return tool.validate(data), k


def _search_route(
    app: FastAPI,
    tool: Tool,
    service: Service,
    blocking: Blocking,
    image_url_for: UrlFor,
) -> None:
    model = query_model(tool)

    async def search(request: Request, params: Annotated[model, Query()]) -> dict[str, Any]:  # type: ignore[valid-type]
        args, k = _split(params, tool)
        hits = await blocking(lambda: service.search(tool, args, k))
        return {"mode": tool.key, "tool": tool.name, "results": service.rows(hits, image_url_for(request))}

    search.__doc__ = f"{tool.description()} (`{tool.name}`: the same JSON as `ravenmem search --json`)"
    app.get(f"/search/{tool.key}", tags=["search"], name=tool.name, summary=tool.summary)(search)


def _image_upload_route(
    app: FastAPI,
    service: Service,
    blocking: Blocking,
    image_url_for: UrlFor,
    gate: DecodeGate | None,
) -> None:
    tool = TOOLS["search_image"]
    model = query_model(tool)

    async def search_upload(
        request: Request,
        params: Annotated[model, Query()],  # type: ignore[valid-type]
        image: Annotated[UploadFile, File(description="the query picture, JPEG or PNG")],
    ) -> dict[str, Any]:
        """Memories that look like an uploaded picture (filters as in the query string)."""
        args, k = _split(params, tool)
        if getattr(args, "memory_id", None) is not None:
            raise InputError("give memory_id or an uploaded image, not both")
        data = await image.read()
        rgb = await run_in_threadpool(decode_image, data, service.cfg.max_pixels, "image", gate)
        hits = await blocking(lambda: service.search(tool, args, k, image=rgb))
        return {"mode": tool.key, "tool": tool.name, "results": service.rows(hits, image_url_for(request))}

    app.post("/search/image", tags=["search"], name="search_image_upload", summary=tool.summary)(
        search_upload
    )
