"""Every failure as `{"error": "<one line>"}`: a 4xx for what the caller can fix, 503 when the
service is busy, 507 when the disk is full (reads go on), and a bare 500 (details in the
service log, never in the response) for anything else."""

from __future__ import annotations

import logging
from collections.abc import Awaitable
from pathlib import Path
from typing import TypeVar

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from starlette.exceptions import HTTPException

from ..errors import NotFoundError, RavenmemError, one_line
from ..fsio import DiskFullError, disk_full
from ..runtime.images import TooLargeError
from ..runtime.live import BusyError

log = logging.getLogger(__name__)
T = TypeVar("T")


def _one_line(text: str, limit: int = 300) -> str:
    line = one_line(text)
    return line if len(line) <= limit else line[: limit - 3] + "..."


def add_error_handlers(app: FastAPI, folder: Path) -> None:
    """Every failure as `{"error": "<one line>"}`: 4xx for the caller's mistakes, a bare 500 else.
    Messages name the memory folder by its name, not by where it lies on this machine."""
    where = sorted({str(folder), str(folder.resolve())}, key=len, reverse=True)

    def private(message: str) -> str:
        for w in where:
            message = message.replace(w, folder.name)
        return message

    def reply(status: int, message: str, headers: dict[str, str] | None = None) -> JSONResponse:
        return JSONResponse({"error": _one_line(message)}, status_code=status, headers=headers)

    @app.exception_handler(BusyError)
    async def busy(request: Request, exc: BusyError) -> JSONResponse:
        return reply(503, str(exc), {"Retry-After": "1"})

    @app.exception_handler(TooLargeError)
    async def too_large(request: Request, exc: TooLargeError) -> JSONResponse:
        return reply(413, str(exc))

    @app.exception_handler(DiskFullError)
    async def full(request: Request, exc: DiskFullError) -> JSONResponse:
        return reply(507, private(str(exc)))

    @app.exception_handler(RavenmemError)
    async def user_error(request: Request, exc: RavenmemError) -> JSONResponse:
        return reply(400, private(str(exc)))

    @app.exception_handler(NotFoundError)
    async def not_found(request: Request, exc: NotFoundError) -> JSONResponse:
        return reply(404, str(exc))

    @app.exception_handler(RequestValidationError)
    async def invalid(request: Request, exc: RequestValidationError) -> JSONResponse:
        errs = exc.errors()
        if not errs:
            return reply(422, "invalid request")
        e = errs[0]
        if e.get("type") == "json_invalid":
            why = (e.get("ctx") or {}).get("error")
            return reply(422, f"body: not valid JSON ({why})" if why else "body: not valid JSON")
        loc = [str(p) for p in e.get("loc", ())]
        if len(loc) > 1 and loc[0] in ("query", "body", "path", "form", "header"):
            loc = loc[1:]
        where = ".".join(loc) or "request"
        msg = str(e.get("msg", "invalid")).removeprefix("Value error, ")
        return reply(422, f"{where}: {msg}")

    @app.exception_handler(HTTPException)
    async def http_error(request: Request, exc: HTTPException) -> JSONResponse:
        return reply(exc.status_code, str(exc.detail), dict(exc.headers or {}))

    @app.exception_handler(TimeoutError)
    async def timeout(request: Request, exc: TimeoutError) -> JSONResponse:
        return reply(504, "timed out")

    @app.exception_handler(Exception)
    async def crash(request: Request, exc: Exception) -> JSONResponse:
        no_space = disk_full(exc)  # SQLite's "database or disk is full", an OSError ENOSPC, ...
        if no_space is not None:
            log.warning("%s %s: %s", request.method, request.url.path, no_space)
            return reply(507, private(str(no_space)))
        log.error("%s %s failed", request.method, request.url.path, exc_info=exc)
        return reply(500, "internal error; the service log has the details")


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
