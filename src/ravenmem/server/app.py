"""The HTTP API (FastAPI): thin routes over `Service`, the page, and `/mcp`.

The search routes are generated from the tools table (`search_routes`); errors are one line of
JSON (`http_errors`); who may call is decided by `security.Guard`.
"""

from __future__ import annotations

import asyncio
import json
import logging
import math
from collections.abc import AsyncIterator, Awaitable, Callable
from contextlib import asynccontextmanager
from importlib import resources
from typing import Annotated, Any, TypeVar

from fastapi import FastAPI, File, Form, Query, Request, UploadFile
from fastapi.responses import FileResponse, JSONResponse, Response, StreamingResponse
from fastapi.staticfiles import StaticFiles
from starlette.concurrency import run_in_threadpool
from starlette.exceptions import HTTPException
from starlette.routing import Route

from ..errors import InputError, NotFoundError
from ..fsio import disk_full
from ..runtime.ask import AskArgs
from ..runtime.events import StreamRefused
from ..runtime.images import decode_depth, decode_image
from ..runtime.service import Service
from ..types import Frame, MemoryRecord, Pose, check_time
from .http_errors import add_error_handlers
from .search_routes import add_search_routes
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

    # ---------------------------------------------------------------- status
    @app.get("/health", tags=["status"])
    async def health() -> dict[str, Any]:
        """Up and serving; how many memories it holds."""
        return {"status": "ok", "memories": await blocking(service.mem.count)}

    @app.get("/info", tags=["status"])
    async def info() -> dict[str, Any]:
        """What `ravenmem info --json` prints, plus the live counts and how questions are answered."""
        return await blocking(service.info)

    # ---------------------------------------------------------------- searches (from TOOLS)
    add_search_routes(app, service, blocking, image_url_for, gate)

    # ---------------------------------------------------------------- questions
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

    # ---------------------------------------------------------------- memories
    @app.post("/memories", tags=["memories"], status_code=201)
    async def add_memory(
        request: Request,
        image: Annotated[UploadFile, File(description="the camera frame, JPEG or PNG")],
        x: Annotated[float, Form(description="map x, metres")],
        y: Annotated[float, Form(description="map y, metres")],
        z: Annotated[float, Form(description="height, metres")] = 0.0,
        yaw: Annotated[float | None, Form(description="heading, radians (or give qx..qw)")] = None,
        qx: Annotated[float | None, Form()] = None,
        qy: Annotated[float | None, Form()] = None,
        qz: Annotated[float | None, Form()] = None,
        qw: Annotated[float | None, Form()] = None,
        t: Annotated[float | None, Form(description="Unix seconds (default: now)")] = None,
        source: Annotated[
            str, Form(max_length=200, description="camera name: keyframes are per source")
        ] = "live",
        depth: Annotated[
            UploadFile | None,
            File(
                description="depth for the map: a 16-bit PNG (units per metre: depth_scale) or .npy in metres"
            ),
        ] = None,
        depth_scale: Annotated[float, Form(description="16-bit depth units per metre (1000: mm)")] = 1000.0,
    ) -> Response:
        """Live add: the frame goes through the online keyframe rule, the embedder and the store.
        201 with the new memory once it is durable, or 200 with the reason it was skipped."""
        if service.writer is None:
            raise InputError("this service is read-only")
        pose = _pose(x, y, z, yaw, (qx, qy, qz, qw))
        when = _now() if t is None else check_time(t, "t")
        data = await image.read()
        rgb = await run_in_threadpool(decode_image, data, cfg.max_pixels, "image", gate)
        Frame(
            image=rgb, t=when, pose=pose, source=source
        ).check()  # what the memory takes, before it is queued
        metres = None
        if depth is not None:
            raw = await depth.read()
            metres = await run_in_threadpool(decode_depth, raw, cfg.max_pixels, depth_scale, "depth")
        # off the event loop: the cheap admission steps (and the map, for depth) run in submit
        fut = await run_in_threadpool(service.writer.submit, rgb, pose, when, source, metres)
        try:
            res = await no_space(asyncio.wait_for(asyncio.wrap_future(fut), cfg.timeout_s))
        except asyncio.TimeoutError:
            raise HTTPException(504, f"the frame was not stored within {cfg.timeout_s:g} s") from None
        body = res.as_json()
        if not res.stored:
            return JSONResponse(body, status_code=200)
        assert res.id is not None
        rec = await blocking(lambda: service.record(res.id))  # type: ignore[arg-type]
        body["memory"] = service.record_json(rec, image_url_for(request))
        return JSONResponse(body, status_code=201)

    @app.get("/memories/{memory_id}", tags=["memories"])
    async def get_memory(memory_id: int, request: Request) -> dict[str, Any]:
        """One memory: time, pose, OCR text, image URL."""
        rec = await blocking(lambda: service.record(memory_id))
        return service.record_json(rec, image_url_for(request))

    @app.get("/memories/{memory_id}/image", tags=["memories"], response_class=FileResponse)
    async def memory_image(memory_id: int) -> FileResponse:
        """The memory's picture (its stored thumbnail); only files inside the memory folder."""
        rec = await blocking(lambda: service.record(memory_id))
        path = service.image_file(rec)
        if path is None:
            raise NotFoundError(f"memory {memory_id} has no picture stored in the memory folder")
        return FileResponse(path, headers={"Cache-Control": "private, max-age=3600"})

    @app.get("/trajectory", tags=["memories"])
    async def trajectory(
        max_points: Annotated[
            int, Query(ge=2, le=100_000, description="thin the path to this many")
        ] = 20_000,
    ) -> dict[str, Any]:
        """Every memory's [id, t, x, y, yaw], chronological (the page's map)."""
        return await blocking(lambda: service.trajectory(max_points))

    @app.get("/map", tags=["memories"])
    async def occupancy_map(request: Request) -> dict[str, Any]:
        """Where the memory's occupancy map lies: `extent` [xmin, ymin, xmax, ymax] in metres,
        `resolution` (m per cell) and the URL of its picture (north up); 404 without a map."""
        found = await blocking(service.occupancy_map)
        if found is None:
            raise NotFoundError("this memory has no occupancy map (exploration writes one)")
        return {**found[1], "image": f"{str(request.base_url).rstrip('/')}/map.png"}

    @app.get("/map.png", tags=["memories"], response_class=Response)
    async def occupancy_map_png() -> Response:
        """The occupancy map: unknown grey, free white, explored light blue, occupied black."""
        found = await blocking(service.occupancy_map)
        if found is None:
            raise NotFoundError("this memory has no occupancy map (exploration writes one)")
        return Response(found[0], media_type="image/png", headers={"Cache-Control": "no-cache"})

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

    # ---------------------------------------------------------------- the page and MCP
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
    app.router.routes.append(
        Route("/mcp", endpoint=StreamableHTTPASGIApp(mcp_manager), include_in_schema=False)
    )
    service.set_image_url(picture_url(""))
    return app


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


async def no_space(work: Awaitable[T]) -> T:
    """`work`, with a full disk as one `DiskFullError` (HTTP 507) instead of whatever raised it."""
    try:
        return await work
    except Exception as e:
        full = disk_full(e)
        if full is None:
            raise
        log.warning("%s", full)
        raise full from None


def _pose(x: float, y: float, z: float, yaw: float | None, quat: tuple[float | None, ...]) -> Pose:
    given = [q is not None for q in quat]
    try:
        if any(given):
            if not all(given):
                raise InputError("give all of qx, qy, qz, qw, or none")
            if yaw is not None:
                raise InputError("give yaw or a quaternion (qx..qw), not both")
            qx, qy, qz, qw = (float(q) for q in quat)  # type: ignore[arg-type]
            return Pose.from_quaternion(x, y, z, qx, qy, qz, qw)
        return Pose(x, y, z, 0.0 if yaw is None else yaw)
    except ValueError as e:
        raise InputError(f"pose: {e}") from None


def _now() -> float:
    import time

    return time.time()


def _sse(kind: str, data: dict[str, Any]) -> str:
    seq = data.get("seq")
    head = f"id: {seq}\n" if seq is not None else ""
    return f"{head}event: {kind}\ndata: {json.dumps(data, allow_nan=False, default=_finite)}\n\n"


def _finite(v: Any) -> Any:
    return None if isinstance(v, float) and not math.isfinite(v) else str(v)
