"""A real service on 127.0.0.1 (uvicorn in a thread, a free port) over a small real memory.

The memory uses the colour test embedder (exact and instant), so route tests check behaviour,
not model quality; `ravenmem serve` itself runs on a real offline-embedder memory in
test_serve_cli.py.
"""

from __future__ import annotations

import os
import re
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import httpx
import pytest

pytest.importorskip("fastapi", reason="the service needs the serve extra: pip install 'ravenmem[serve]'")
pytest.importorskip("mcp", reason="the service needs the serve extra: pip install 'ravenmem[serve]'")
import uvicorn  # noqa: E402

import ravenmem
from ravenmem.runtime.service import Service, ServiceConfig
from ravenmem.server.app import create_app
from ravenmem.server.run import make_server
from tests.agent.conftest import scene_frames
from tests.conftest import ColorEmbedder

REPO = Path(__file__).resolve().parents[2]
SERVE_COLOR = REPO / "tests" / "server" / "serve_color.py"  # `ravenmem` with the colour embedder registered
TOKEN = "s3cret-token-for-tests-0123456789"


def make_memory(path: Path) -> ravenmem.Memory:
    mem = ravenmem.create(path, embedder=ColorEmbedder(), ocr=False, thumb_size=32)
    mem.add_frames(scene_frames())  # the agent tests' scene: the same 12 colours and poses
    return mem


class ServerThread:
    """uvicorn serving an app in a thread on a socket bound here (port 0: a free one)."""

    def __init__(self, app, service: Service, host: str = "127.0.0.1") -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM, socket.IPPROTO_TCP)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self.sock.bind((host, 0))
        self.port = self.sock.getsockname()[1]
        self.url = f"http://{host}:{self.port}"
        cfg = uvicorn.Config(app, log_level="warning", timeout_graceful_shutdown=1)
        self.server = make_server(cfg, service)
        self.thread = threading.Thread(target=self.server.run, kwargs={"sockets": [self.sock]}, daemon=True)

    def __enter__(self) -> ServerThread:
        self.thread.start()
        deadline = time.monotonic() + 30
        while not self.server.started:
            if time.monotonic() > deadline or not self.thread.is_alive():
                raise RuntimeError("the test server did not start")
            time.sleep(0.02)
        return self

    def __exit__(self, *exc: object) -> None:
        self.server.should_exit = True
        self.thread.join(30)
        self.sock.close()


@dataclass
class Served:
    url: str
    service: Service
    mem: ravenmem.Memory
    token: str | None = None

    def client(self, token: str | None = None, **kw) -> httpx.Client:
        headers = {"Authorization": f"Bearer {token}"} if token else {}
        return httpx.Client(base_url=self.url, headers=headers, timeout=30, **kw)


def serve_memory(mem: ravenmem.Memory, token: str | None = None, **cfg) -> Iterator[Served]:
    service = Service(mem, ServiceConfig(**cfg))
    app = create_app(service, token=token, loopback=True)
    with ServerThread(app, service) as srv:
        yield Served(srv.url, service, mem, token)


@pytest.fixture
def served(tmp_path) -> Iterator[Served]:
    yield from serve_memory(make_memory(tmp_path / "scene.mem"))


@pytest.fixture
def served_token(tmp_path) -> Iterator[Served]:
    yield from serve_memory(make_memory(tmp_path / "scene.mem"), token=TOKEN)


def serve_subprocess(
    mem_path: Path,
    *extra: str,
    colour: bool = True,
    health_token: str | None = None,
    entry: Path | None = None,
) -> tuple[subprocess.Popen[str], str]:
    """`ravenmem serve --port 0` in a subprocess (with the colour test embedder registered unless
    `colour=False`; `entry`: another script that runs it); returns it and its URL once /health
    answers. Its log goes to a file (a pipe nobody reads could fill up and stop it)."""
    script = entry or SERVE_COLOR
    command = [str(script)] if colour or entry else ["-m", "ravenmem.cli.main"]
    log = tempfile.TemporaryFile("w+")  # noqa: SIM115 - lives as long as the process
    proc = subprocess.Popen(
        _serve_argv(command, mem_path, "--log-level", "warning", *extra),
        stdout=subprocess.PIPE,
        stderr=log,
        text=True,
        env=_serve_env(),
    )
    assert proc.stdout is not None
    line = proc.stdout.readline()
    m = re.search(r"at (http://127\.0\.0\.1:\d+)/", line)
    if m is None:
        proc.kill()
        proc.wait()
        log.seek(0)
        raise AssertionError(f"no URL in {line!r}: {log.read()[-2000:]}")
    url = m.group(1)
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        try:
            auth = {"Authorization": f"Bearer {health_token}"} if health_token else {}
            if httpx.get(url + "/health", headers=auth, timeout=2).status_code == 200:
                return proc, url
        except httpx.HTTPError:
            time.sleep(0.1)
    proc.kill()
    raise AssertionError("the service did not answer /health")


def serve_refused(mem_path: Path, *extra: str) -> subprocess.CompletedProcess[str]:
    """`ravenmem serve --port 0` (colour test embedder) run to its end: for a service that must
    refuse to start (bad options, another writer); its exit code and output."""
    return subprocess.run(
        _serve_argv([str(SERVE_COLOR)], mem_path, *extra),
        capture_output=True,
        text=True,
        env=_serve_env(),
        timeout=120,
    )


def _serve_env() -> dict[str, str]:
    """This checkout's sources first; no token or server of the developer's shell."""
    env = {k: v for k, v in os.environ.items() if k not in ("RAVENMEM_TOKEN", "RAVENMEM_SERVER")}
    env["PYTHONPATH"] = f"{REPO / 'src'}{os.pathsep}{REPO}"
    return env


def _serve_argv(command: list[str], mem_path: Path, *extra: str) -> list[str]:
    return [sys.executable, *command, "serve", "--memory", str(mem_path), "--port", "0", *extra]


def stop(proc: subprocess.Popen[str]) -> None:
    """Stop a service as Ctrl-C does (SIGINT); killed when it has not exited within 60 s."""
    proc.send_signal(signal.SIGINT)
    try:
        proc.wait(60)
    finally:
        if proc.poll() is None:
            proc.kill()


def running_service(mem_path: Path, *extra: str, **kw: Any) -> Iterator[str]:
    """`serve_subprocess` for a fixture: yields its URL, stops it afterwards."""
    proc, url = serve_subprocess(mem_path, *extra, **kw)
    try:
        yield url
    finally:
        stop(proc)
