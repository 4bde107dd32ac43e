"""Who may talk to the service, and how much they may send.

- On a loopback address no token is needed, but a request must name a loopback host (so a web
  page elsewhere cannot reach the service through DNS rebinding) and must not come from another
  origin (so a page elsewhere cannot make the browser post frames or questions: no CORS).
- On any other address the service refuses to start without a token, and every route that
  touches the memory (searches, images, events, MCP, the page's API calls) needs
  `Authorization: Bearer <token>`. The page's own files and the API description are public:
  they hold nothing of the memory.
- A body over the size limit is refused (413): before it is read when its Content-Length says
  so, and at the limit while it is read otherwise (chunked uploads).
- A body must arrive within a deadline (`body_timeout`, 30 s by default, from the first read
  of it): a client that sends a byte a second (slowloris) is answered 408 and cut off.
- A query string that is not UTF-8 once percent-decoded (`q=%FF%FE`) is refused (400) rather
  than searched as replacement characters.
"""

from __future__ import annotations

import asyncio
import hmac
import ipaddress
import json
import time
from urllib.parse import unquote_to_bytes, urlsplit

from starlette.exceptions import HTTPException
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from ..errors import InputError

PUBLIC = ("/", "/static/", "/docs", "/docs/oauth2-redirect", "/openapi.json", "/redoc", "/favicon.ico")
DOCS_STATIC = "/docs-static"  # Swagger UI's and ReDoc's own files, when served locally
LOOPBACK_NAMES = ("localhost", "localhost.")
MIN_TOKEN = 16


def is_loopback(host: str) -> bool:
    """True for 127.0.0.0/8, ::1 and localhost: addresses no other machine can reach."""
    h = host.strip("[]").lower()
    if h in LOOPBACK_NAMES:
        return True
    try:
        return ipaddress.ip_address(h).is_loopback
    except ValueError:
        return False


def check_bind(host: str, token: str | None) -> None:
    """Refuse (one line) to serve a non-loopback address without a token, or with a weak one."""
    if token is not None and len(token) < MIN_TOKEN:
        raise InputError(f"--token must be at least {MIN_TOKEN} characters (e.g. `openssl rand -hex 16`)")
    if not is_loopback(host) and not token:
        raise InputError(
            f"refusing to serve {host} without a token: other machines could read the memory; "
            "pass --token or RAVENMEM_TOKEN, or bind 127.0.0.1"
        )


def is_public(path: str) -> bool:
    return path == "/" or path.startswith(("/static/", DOCS_STATIC + "/")) or path in PUBLIC


class Guard:
    """ASGI middleware enforcing the rules of the module docstring on HTTP and WebSocket."""

    def __init__(
        self,
        app: ASGIApp,
        token: str | None,
        loopback: bool,
        max_body: int | None = None,
        body_timeout: float | None = 30.0,
    ) -> None:
        self.app = app
        self.token = token.encode() if token else None
        self.loopback = loopback
        self.max_body = max_body
        self.body_timeout = body_timeout

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] not in ("http", "websocket"):
            await self.app(scope, receive, send)
            return
        headers = {k.decode("latin-1").lower(): v.decode("latin-1") for k, v in scope.get("headers", [])}
        host = headers.get("host", "")
        refusal = self._refuse(scope, headers, host)
        if refusal is None:
            limited = scope["type"] == "http" and (self.max_body or self.body_timeout)
            await self.app(scope, self._limited(receive) if limited else receive, send)
            return
        status, message = refusal
        if scope["type"] == "websocket":
            await send({"type": "websocket.close", "code": 1008})
            return
        body = json.dumps({"error": message}).encode()
        extra = [(b"www-authenticate", b"Bearer")] if status == 401 else []
        await send(
            {
                "type": "http.response.start",
                "status": status,
                "headers": [
                    (b"content-type", b"application/json"),
                    (b"content-length", str(len(body)).encode()),
                ]
                + extra,
            }
        )
        await send({"type": "http.response.body", "body": body})

    def _limited(self, receive: Receive) -> Receive:
        """`receive` that stops a body at the size limit (the app answers the HTTPException with
        413) and at the deadline (408), counted from the first time the app reads the body."""
        limit, seen = self.max_body, 0
        deadline: float | None = None
        timeout = self.body_timeout

        async def counted() -> Message:
            nonlocal seen, deadline, timeout
            if timeout is None:
                message = await receive()
            else:
                if deadline is None:
                    deadline = time.monotonic() + timeout
                try:
                    message = await asyncio.wait_for(receive(), max(deadline - time.monotonic(), 0.001))
                except asyncio.TimeoutError:
                    raise HTTPException(
                        408, f"the request body did not arrive within {timeout:g} s"
                    ) from None
            if message["type"] == "http.request":
                seen += len(message.get("body", b""))
                if limit is not None and seen > limit:
                    raise HTTPException(413, f"request body is over the limit of {limit} bytes")
                if not message.get("more_body", False):
                    deadline = None  # the body is complete: later reads (disconnects) wait freely
                    timeout = None
            return message

        return counted

    def _refuse(self, scope: Scope, headers: dict[str, str], host: str) -> tuple[int, str] | None:
        if self.loopback and not self.token and not is_loopback(_hostname(host)):
            return 403, f"host {host!r} is not a loopback name; this service answers on loopback only"
        origin = headers.get("origin")
        if origin is not None and not _same_origin(origin, host):
            return 403, "requests from another origin are refused (no CORS)"
        if self.token is not None and not is_public(scope.get("path", "")):
            auth = headers.get("authorization", "")
            scheme, _, given = auth.partition(" ")
            if scheme.lower() != "bearer" or not hmac.compare_digest(given.strip().encode(), self.token):
                return 401, "missing or wrong bearer token (send Authorization: Bearer <token>)"
        size = headers.get("content-length", "")
        if self.max_body is not None and size.isdigit() and int(size) > self.max_body:
            return 413, f"request body of {int(size)} bytes is over the limit of {self.max_body}"
        bad = _not_utf8(scope.get("query_string", b""))
        if bad is not None:
            return 400, f"query string: {bad!r} is not valid UTF-8 once percent-decoded"
        return None


def _not_utf8(query: bytes) -> str | None:
    """The first `name=value` of a query string that is not UTF-8 once percent-decoded, else None."""
    for part in query.split(b"&"):
        try:
            unquote_to_bytes(part.replace(b"+", b" ")).decode("utf-8")
        except UnicodeDecodeError:
            return part.decode("latin-1")[:60]
    return None


def _hostname(host: str) -> str:
    """`127.0.0.1:8765` -> `127.0.0.1`, `[::1]:8765` -> `::1`."""
    if host.startswith("["):
        return host[1 : host.find("]")] if "]" in host else host
    return host.rsplit(":", 1)[0] if host.count(":") == 1 else host


def _same_origin(origin: str, host: str) -> bool:
    try:
        parts = urlsplit(origin)
    except ValueError:
        return False
    return parts.scheme in ("http", "https") and parts.netloc.lower() == host.lower()
