"""Start the service: check the address and token, open the memory, load the models, listen.

The models are loaded (and run once) before the port opens, so a service that answers
`/health` answers searches at warm speed. The listening socket is opened here rather than by
uvicorn so that a taken port is a one-line error, and `port=0` picks a free one (printed).
"""

from __future__ import annotations

import logging
import socket
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, TextIO

from ..errors import InputError, require
from ..runtime.service import Service, ServiceConfig
from .security import check_bind, is_loopback

log = logging.getLogger(__name__)


def listen(host: str, port: int) -> socket.socket:
    """A bound, listening TCP socket (IPv6 when the host is an IPv6 address)."""
    if not 0 <= port <= 65535:
        raise InputError(f"--port must be from 0 to 65535, got {port}")
    try:
        infos = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE)
    except socket.gaierror as e:
        raise InputError(f"cannot listen on {host}: {e.strerror}") from None
    family, kind, proto, _, addr = infos[0]
    # the protocol number matters: asyncio turns Nagle's algorithm off (TCP_NODELAY) only on
    # sockets that say they are TCP, and with it on every response waits ~40 ms for an ACK
    sock = socket.socket(family, kind, proto or socket.IPPROTO_TCP)
    try:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        sock.bind(addr)
        sock.listen(128)
    except OSError as e:
        sock.close()
        raise InputError(f"cannot listen on {host}:{port}: {e.strerror}") from None
    sock.set_inheritable(True)
    return sock


def serve(
    memory: Path,
    host: str = "127.0.0.1",
    port: int = 8765,
    token: str | None = None,
    cfg: ServiceConfig | None = None,
    log_level: str = "info",
    out: TextIO | None = None,
    create: dict[str, Any] | None = None,
    wait: float = 0.0,
    links: Sequence[Callable[[Service], Any]] = (),
    map_id: str | None = None,
) -> None:
    """Serve a memory until interrupted (Ctrl-C or SIGTERM store what is queued, then close).

    `create` (keyword arguments of `ravenmem.create`) makes a new, empty memory when the folder
    holds none yet: a robot can start from nothing and fill it with live adds. Unless read-only,
    the service holds the memory's writer lock for its whole life (`wait` seconds for another
    writer to finish; a busy memory is a one-line error naming the holder).
    `links` start other front ends on the service before it listens (the robot link:
    `ravenmem.ros.zenoh.start_link`); they are closed with it. `map_id`: the map live poses
    are in (`Memory.claim_map`: a memory in another map is refused before the port opens)."""
    check_bind(host, token)
    if log_level not in ("critical", "error", "warning", "info", "debug", "trace"):
        raise InputError(f"--log-level: expected critical, error, warning, info or debug, got {log_level!r}")
    require("fastapi", "serve")
    uvicorn = require("uvicorn", "serve")
    import ravenmem

    from ..memory.folder import MANIFEST, is_memory
    from .app import create_app

    cfg = cfg or ServiceConfig()
    sock = listen(host, port)
    try:
        exists = is_memory(Path(memory))
        if not exists and create is None:
            if Path(memory).is_dir() and any(Path(memory).iterdir()):
                raise InputError(f"{memory} is not a memory (no {MANIFEST} in it)")
            raise InputError(f"memory {memory} does not exist (pass --create to start an empty one)")
        if exists:
            mem = ravenmem.open(memory, writable=cfg.writable, wait=wait or False)
        else:
            mem = ravenmem.create(memory, **(create or {}), wait=wait or False)
        if map_id is not None:
            try:
                if cfg.writable:
                    mem.claim_map(map_id, what="--map-id")
                elif map_id != mem.map_id:
                    raise InputError(f"--map-id {map_id!r}: memory {memory} is in map {mem.map_id!r}")
            except BaseException:
                mem.close()
                raise
        service = Service(mem, cfg)
        service.warm_up()
        try:
            for start_link in links:
                start_link(service)
        except BaseException:
            service.close()
            raise
        app = create_app(service, token=token, loopback=is_loopback(host))
    except BaseException:
        sock.close()
        raise
    bound = sock.getsockname()[1]
    shown = f"[{host}]" if ":" in host else host
    url = f"http://{shown}:{bound}/"
    out = out or sys.stdout
    out.write(
        f"ravenmem: serving {memory} ({mem.count()} memories) at {url}"
        f"{'#token=<your token>' if token else ''}  (API: {url}docs, MCP: {url}mcp)\n"
    )
    out.flush()
    config = uvicorn.Config(  # type: ignore[attr-defined]
        app,
        log_level=log_level,
        timeout_graceful_shutdown=3,
        timeout_keep_alive=30,
        h11_max_incomplete_event_size=64 * 1024,  # request line + headers
        server_header=False,
    )
    make_server(config, service).run(sockets=[sock])


def make_server(config: Any, service: Service) -> Any:
    """A uvicorn server that ends the event streams as soon as it starts shutting down (an open
    stream would otherwise hold the graceful shutdown until its timeout)."""
    import uvicorn

    class ServiceServer(uvicorn.Server):
        async def shutdown(self, sockets: list[socket.socket] | None = None) -> None:
            service.stop_streams()
            await super().shutdown(sockets)

    return ServiceServer(config)
