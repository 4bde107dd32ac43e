"""The memory routes: live adds (`POST /memories`), one memory and its picture, the trajectory
and the occupancy map, thin over `Service` (the frame is checked once, at the writer's door)."""

from __future__ import annotations

import asyncio
from typing import Annotated, Any

from fastapi import FastAPI, File, Form, Query, Request, UploadFile
from fastapi.responses import FileResponse, JSONResponse, Response
from starlette.concurrency import run_in_threadpool
from starlette.exceptions import HTTPException

from ..errors import InputError, NotFoundError
from ..runtime.images import DecodeGate, decode_depth, decode_image
from ..runtime.service import Service
from ..types import Pose, check_time
from .http_errors import no_space
from .search_routes import Blocking, UrlFor


def add_memory_routes(
    app: FastAPI, service: Service, blocking: Blocking, image_url_for: UrlFor, gate: DecodeGate | None
) -> None:
    """The routes of the memory itself (see the module docstring)."""
    cfg = service.cfg

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
        metres = None
        if depth is not None:
            raw = await depth.read()
            metres = await run_in_threadpool(decode_depth, raw, cfg.max_pixels, depth_scale, "depth")
        # off the event loop: the frame is checked once, at the writer's door (what the memory
        # takes, before it is queued); the cheap admission steps (and the map, for depth) run in submit
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

    _read_routes(app, service, blocking, image_url_for)


def _read_routes(app: FastAPI, service: Service, blocking: Blocking, image_url_for: UrlFor) -> None:
    """One memory, its picture, the trajectory and the occupancy map."""

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
