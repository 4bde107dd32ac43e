"""The HTTP API (FastAPI): thin routes over `Service`, the page, and `/mcp`.

The search routes are generated from the tools table (`search_routes`); errors are one line of
JSON (`http_errors`); who may call is decided by `security.Guard`.
"""

from __future__ import annotations

import asyncio
import json
import logging
import math
from collections.abc import AsyncIterator, Callable
from contextlib import asynccontextmanager
from dataclasses import dataclass
from importlib import resources
from typing import Any, TypeVar

from fastapi import FastAPI, Request
from fastapi.responses import JSONResponse, Response, StreamingResponse
from fastapi.staticfiles import StaticFiles
from starlette.concurrency import run_in_threadpool
from starlette.exceptions import HTTPException
from starlette.routing import Route

from ..runtime.ask import AskArgs
from ..runtime.events import StreamRefused
from ..runtime.service import Service
from ..types import MemoryRecord
from .http_errors import add_error_handlers, no_space
from .memory_routes import add_memory_routes
from .search_routes import Blocking, UrlFor, add_search_routes
from .security import DOCS_STATIC, Guard

log = logging.getLogger(__name__)
T = TypeVar("T")

KEEPALIVE_S = 15.0
STATIC = resources.files("ravenmem.server") / "static"


def create_app(service: Service, token: str | None = None, loopback: bool = True) -> FastAPI:
    """The service's ASGI app; its lifespan starts and closes `service` (and the memory)."""
    from mcp.server.streamable_http_manager import StreamableHTTPASGIApp, StreamableHTTPSessionManager
    from mcp.server.transport_security import TransportSecuritySettings

    from .mcp_tools import build_server

    cfg = service.cfg
    mcp_manager = StreamableHTTPSessionManager(
        app=build_server(service),
        json_response=True,
        stateless=True,
        # the Guard below already checks Host and Origin on every route, /mcp included
        security_settings=TransportSecuritySettings(enable_dns_rebinding_protection=False),
        max_request_body_size=cfg.max_upload_bytes,
    )

    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        service.start()
        try:
            async with mcp_manager.run():
                yield
        finally:
            await run_in_threadpool(service.close)

    app = _fastapi(
        title="ravenmem",
        version="0.1.0",
        summary="A robot's long-term visual memory: search it, ask it, add to it.",
        lifespan=lifespan,
    )
    app.add_middleware(
        Guard, token=token, loopback=loopback, max_body=cfg.max_upload_bytes, body_timeout=cfg.body_timeout_s
    )
    gate = service.gate  # what the pictures being decoded may hold at once
    add_error_handlers(app, service.mem.path)
    if token:
        _document_bearer(app)

    def image_url_for(request: Request) -> Callable[[MemoryRecord], str | None]:
        return picture_url(str(request.base_url).rstrip("/"))

    def picture_url(base: str) -> Callable[[MemoryRecord], str | None]:
        """A memory's picture URL, or None when the service would not serve one (no picture
        inside the memory folder): a URL is named only when it answers."""
        return lambda rec: f"{base}/memories/{rec.id}/image" if service.image_file(rec) else None

    async def blocking(fn: Callable[[], T]) -> T:
        """Run memory work off the event loop, bounded in time (504 when it takes too long); a
        full disk is one line (507), and reads go on."""
        try:
            return await no_space(asyncio.wait_for(run_in_threadpool(fn), cfg.timeout_s))
        except asyncio.TimeoutError:
            raise HTTPException(504, f"no answer within {cfg.timeout_s:g} s") from None

    # ---------------------------------------------------------------- the routes
    web = Web(service, blocking, image_url_for)
    _status_routes(app, web)
    add_search_routes(app, service, blocking, image_url_for, gate)  # from the tools table
    _ask_route(app, web)
    add_memory_routes(app, service, blocking, image_url_for, gate)
    _event_route(app, web)
    _page_routes(app)
    app.router.routes.append(
        Route("/mcp", endpoint=StreamableHTTPASGIApp(mcp_manager), include_in_schema=False)
    )
    service.set_image_url(picture_url(""))
    return app


@dataclass(frozen=True)
class Web:
    """What the routes share: the service, how memory work runs off the event loop (bounded in
    time), and how a memory's picture is named for a request."""

    service: Service
    blocking: Blocking
    image_url_for: UrlFor


def _status_routes(app: FastAPI, web: Web) -> None:
    service, blocking = web.service, web.blocking

    @app.get("/health", tags=["status"])
    async def health() -> dict[str, Any]:
        """Up and serving; how many memories it holds."""
        return {"status": "ok", "memories": await blocking(service.mem.count)}

    @app.get("/info", tags=["status"])
    async def info() -> dict[str, Any]:
        """What `ravenmem info --json` prints, plus the live counts and how questions are answered."""
        return await blocking(service.info)


def _ask_route(app: FastAPI, web: Web) -> None:
    """`POST /ask`: the body is the one ask request (`runtime.ask.AskArgs`), asked through the
    one path (`Service.ask`); the typed result is written as JSON here, its status from its
    outcome."""
    service, blocking, image_url_for = web.service, web.blocking, web.image_url_for

    @app.post("/ask", tags=["ask"], response_model=None)
    async def ask(body: AskArgs, request: Request) -> dict[str, Any] | JSONResponse:
        """Answer a question as `ravenmem ask --json` does (evidence images as URLs). A question
        that failed gets 502 (504: out of time), an unsupported position 422, each with the
        one-line reason in `error` and the answer in `answer`."""
        result = await blocking(lambda: service.ask(body))
        data = service.result_json(result, image_url_for(request))
        if result.refusal:
            reason = " ".join(result.refusal.split())
            return JSONResponse({"error": reason, "answer": data}, status_code=result.status)
        return data


def _event_route(app: FastAPI, web: Web) -> None:
    service, blocking = web.service, web.blocking

    @app.get("/events", tags=["memories"], response_class=StreamingResponse)
    async def events() -> StreamingResponse:
        """Server-sent events: `memory` (a new memory), `skipped` (a frame the keyframe rule
        dropped) and `answer` (a question answered), as they happen."""
        count = await blocking(service.mem.count)
        try:
            sub = service.bus.subscribe()
        except StreamRefused as e:
            raise HTTPException(503, str(e)) from None

        async def stream() -> AsyncIterator[str]:
            with sub:
                yield _sse("hello", {"type": "hello", "memories": count})
                while True:
                    try:
                        ev = await sub.next(KEEPALIVE_S)
                    except asyncio.TimeoutError:
                        yield ": keep-alive\n\n"
                        continue
                    if ev is None:
                        return
                    yield _sse(str(ev["type"]), ev)

        return StreamingResponse(
            stream(),
            media_type="text/event-stream",
            headers={"Cache-Control": "no-store", "X-Accel-Buffering": "no"},
        )


def _page_routes(app: FastAPI) -> None:
    @app.get("/", include_in_schema=False)
    async def page() -> Response:
        html = (STATIC / "index.html").read_text(encoding="utf-8")
        return Response(html, media_type="text/html; charset=utf-8", headers={"Cache-Control": "no-store"})

    @app.get("/favicon.ico", include_in_schema=False)
    async def favicon() -> Response:
        """The page's icon (an SVG: every browser the page supports shows one)."""
        svg = (STATIC / "favicon.svg").read_bytes()
        return Response(svg, media_type="image/svg+xml", headers={"Cache-Control": "public, max-age=86400"})

    app.mount("/static", StaticFiles(directory=str(STATIC)), name="static")


# ---------------------------------------------------------------------------- helpers
def _fastapi(**kwargs: Any) -> FastAPI:
    """FastAPI whose `/docs` (Swagger UI) and `/redoc` load their scripts from this service, out
    of fastapi-offline's copy (the `api-docs` extra), so they work on a robot without internet;
    without that package they load them from the CDN FastAPI uses by default."""
    try:
        from fastapi_offline import FastAPIOffline
    except ImportError:
        return FastAPI(**kwargs)
    app: FastAPI = FastAPIOffline(static_url=DOCS_STATIC, **kwargs)
    return app


def _document_bearer(app: FastAPI) -> None:
    """Say in the OpenAPI description that every route needs the bearer token (so that /docs
    offers an Authorize button); the Guard middleware is what enforces it."""
    plain = app.openapi

    def openapi() -> dict[str, Any]:
        if app.openapi_schema is None:
            schema = plain()
            schema.setdefault("components", {})["securitySchemes"] = {
                "bearer": {"type": "http", "scheme": "bearer"}
            }
            schema["security"] = [{"bearer": []}]
            app.openapi_schema = schema
        return app.openapi_schema

    app.openapi = openapi  # type: ignore[method-assign]


def _sse(kind: str, data: dict[str, Any]) -> str:
    seq = data.get("seq")
    head = f"id: {seq}\n" if seq is not None else ""
    return f"{head}event: {kind}\ndata: {json.dumps(data, allow_nan=False, default=_finite)}\n\n"


def _finite(v: Any) -> Any:
    return None if isinstance(v, float) and not math.isfinite(v) else str(v)
