"""`ravenmem serve` (a long-running memory over HTTP, with the page and MCP) and `ravenmem mcp`
(the memory as MCP tools over stdio). Both are thin: everything lives in `ravenmem.server`."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Annotated, Any

import typer

from ..errors import InputError
from .options import CONFIG, MEGABYTES, PORT, SECONDS, TIMEOUT, TOOL_CALLS, TOP_K, MemoryOpt

MethodOpt = Annotated[
    str | None,
    typer.Option(help="default way to answer questions (default: raven with a VLM configured, else offline)"),
]
ModelOpt = Annotated[str | None, typer.Option("--model", help="VLM model name (or RAVENMEM_VLM_MODEL)")]
BaseUrlOpt = Annotated[
    str | None, typer.Option("--base-url", help="OpenAI-compatible VLM endpoint (or RAVENMEM_VLM_BASE_URL)")
]
ConfigOpt = Annotated[Path | None, CONFIG, typer.Option("--config", help="config file with a [vlm] section")]
TopKOpt = Annotated[
    str | None,
    TOP_K,
    typer.Option("--top-k", help="default memories per tool call: N, or per tool 'text=30,time=200'"),
]
PresetOpt = Annotated[
    str | None,
    typer.Option(
        help="default preset for questions: raven-qa-human | raven-qa-robot | raven-qa-robot-open | navqa | findingdory"
    ),
]


def _vlm(
    config: Path | None, base_url: str | None, model: str | None, tool_mode: str | None = None
) -> object:
    from ravenmem.agent.config import VLMConfig

    return VLMConfig.resolve(config_path=config, base_url=base_url, model=model, tool_mode=tool_mode)


def serve(
    memory: MemoryOpt,
    host: Annotated[
        str, typer.Option(help="address to listen on; anything but loopback needs --token")
    ] = "127.0.0.1",
    port: Annotated[int, PORT, typer.Option(help="port (0: a free one, printed)")] = 8765,
    token: Annotated[
        str | None,
        typer.Option(
            envvar="RAVENMEM_TOKEN", help="bearer token every request must send (or RAVENMEM_TOKEN)"
        ),
    ] = None,
    keyframes: Annotated[
        str | None,
        typer.Option(
            help="live-add keyframe rules, as for ingest: the default rules when left out, 'all' "
            "(every frame), or e.g. 'fps=2,min_translation=0.1'"
        ),
    ] = None,
    method: MethodOpt = None,
    model: ModelOpt = None,
    base_url: BaseUrlOpt = None,
    tool_mode: Annotated[str | None, typer.Option(help="auto | native | json")] = None,
    config: ConfigOpt = None,
    preset: PresetOpt = None,
    top_k: TopKOpt = None,
    max_tool_calls: Annotated[
        int | None, TOOL_CALLS, typer.Option(help="default tool-call budget per question")
    ] = None,
    max_upload_mb: Annotated[
        float, MEGABYTES, typer.Option(help="largest request body (uploads), MiB")
    ] = 16.0,
    timeout: Annotated[
        float, TIMEOUT, typer.Option(help="seconds a search, question or add may take")
    ] = 120.0,
    body_timeout: Annotated[
        float, TIMEOUT, typer.Option(help="seconds a client may take to send a request body (then 408)")
    ] = 30.0,
    read_only: Annotated[bool, typer.Option("--read-only", help="no live adds (and no writer lock)")] = False,
    wait: Annotated[
        float, SECONDS, typer.Option(help="seconds to wait for another writer of the memory")
    ] = 0.0,
    intrinsics: Annotated[
        str | None,
        typer.Option(
            help="live depth camera (fr1 | fr2 | fr3 | kinect | fx,fy,cx,cy): live adds with depth update the map"
        ),
    ] = None,
    camera_frame: Annotated[
        str, typer.Option(help="live poses are of a 'body' (x forward, z up) or the camera's 'optical' frame")
    ] = "body",
    create: Annotated[
        bool, typer.Option("--create", help="start a new, empty memory when DIR holds none")
    ] = False,
    embedder: Annotated[str, typer.Option(help="with --create: the new memory's embedder")] = "offline",
    ocr: Annotated[bool, typer.Option(help="with --create: read text in live frames (slower)")] = True,
    log_level: Annotated[str, typer.Option(help="critical | error | warning | info | debug")] = "info",
    zenoh: Annotated[
        str | None,
        typer.Option(
            help="ROS 2 topics over Zenoh into the memory, e.g. 'image=camera/color/image_raw,pose=odom"
            ",goal=goal_pose'; also serves ravenmem_msgs/srv/Ask and Search (needs the robot extra; "
            "keys in docs/serve.md)"
        ),
    ] = None,
    zenoh_connect: Annotated[
        list[str] | None,
        typer.Option(help="Zenoh endpoint to connect to, e.g. tcp/192.168.1.10:7447 (repeatable)"),
    ] = None,
    zenoh_listen: Annotated[
        list[str] | None, typer.Option(help="Zenoh endpoint to listen on, e.g. tcp/0.0.0.0:7447 (repeatable)")
    ] = None,
    zenoh_config: Annotated[
        Path | None, typer.Option(help="a Zenoh JSON5 config file (routers, TLS, ...)")
    ] = None,
    map_id: Annotated[
        str | None,
        typer.Option(
            help="the map live poses are in (a memory in another map is refused; see `ravenmem align`)"
        ),
    ] = None,
) -> None:
    """Serve a memory: HTTP API (/docs), a page for people (/), MCP (/mcp), live adds, a robot."""
    from ravenmem.agent.presets import parse_top_k
    from ravenmem.ingest.depth import parse_intrinsics
    from ravenmem.ingest.keyframes import KeyframeConfig
    from ravenmem.runtime.service import ServiceConfig
    from ravenmem.server.run import serve as run_serve

    cfg = ServiceConfig(
        keyframes=KeyframeConfig.from_spec(keyframes),
        method=method,
        vlm=_vlm(config, base_url, model, tool_mode),  # type: ignore[arg-type]
        preset=preset,
        top_k=parse_top_k(top_k),
        max_tool_calls=max_tool_calls,
        max_upload_bytes=int(max_upload_mb * 2**20),
        timeout_s=timeout,
        body_timeout_s=body_timeout,
        writable=not read_only,
        intrinsics=parse_intrinsics(intrinsics) if intrinsics else None,
        camera_frame=camera_frame,
    )
    new = {"embedder": embedder, "ocr": ocr} if create else None
    links = [_zenoh_link(zenoh, zenoh_connect, zenoh_listen, zenoh_config, read_only)] if zenoh else []
    if not zenoh and (zenoh_connect or zenoh_listen or zenoh_config):
        raise InputError("--zenoh-connect, --zenoh-listen and --zenoh-config need --zenoh")
    run_serve(
        memory,
        host=host,
        port=port,
        token=token or None,
        cfg=cfg,
        log_level=log_level,
        create=new,
        wait=wait,
        links=links,
        map_id=map_id,
    )


def _zenoh_link(
    spec: str, connect: list[str] | None, listen: list[str] | None, config: Path | None, read_only: bool
) -> Callable[[Any], Any]:
    """Check `--zenoh` before anything opens; return what starts the link on the service."""
    from ravenmem.errors import require
    from ravenmem.ros.link import LinkConfig
    from ravenmem.ros.zenoh import ZenohEndpoints, start_link

    if read_only:
        raise InputError("--zenoh adds frames to the memory: it cannot run with --read-only")
    cfg = LinkConfig.from_spec(spec)
    require("zenoh", "robot")
    if config is not None and not config.is_file():
        raise InputError(f"zenoh config {config} is not a file")
    endpoints = ZenohEndpoints(tuple(connect or ()), tuple(listen or ()), config)
    return lambda service: start_link(service, cfg, endpoints)


def mcp(
    memory: MemoryOpt,
    method: MethodOpt = None,
    model: ModelOpt = None,
    base_url: BaseUrlOpt = None,
    config: ConfigOpt = None,
    preset: PresetOpt = None,
    top_k: TopKOpt = None,
) -> None:
    """Serve a memory's tools (search_text, search_image, search_time, search_position, ask) to an
    MCP client over stdio, e.g. `{"command": "ravenmem", "args": ["mcp", "--memory", "DIR"]}`."""
    import anyio

    import ravenmem
    from ravenmem.errors import require
    from ravenmem.runtime.service import Service, ServiceConfig

    require("mcp", "serve")
    from ravenmem.agent.presets import parse_top_k
    from ravenmem.server.mcp_tools import run_stdio

    cfg = ServiceConfig(
        method=method,
        vlm=_vlm(config, base_url, model),  # type: ignore[arg-type]
        preset=preset,
        top_k=parse_top_k(top_k),
        writable=False,
    )
    service = Service(ravenmem.open(memory), cfg)
    try:
        anyio.run(run_stdio, service)
    finally:
        service.close()


def register(app: typer.Typer) -> None:
    """Add `serve` and `mcp` to the ravenmem command."""
    app.command("serve")(serve)
    app.command("mcp")(mcp)
