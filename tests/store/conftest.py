"""Fixtures for the store tests: backends to run the shared behaviour tests against, data.

Backends: `local` and `milvus` (Milvus Lite file in tmp) always; `milvus-server` (marked
`server`) starts a Milvus standalone server: the `milvus-server` script from the PyPI package
`milvus` found via $RAVENMEM_MILVUS_SERVER or PATH, or an already running one named by
$RAVENMEM_MILVUS_URI (host:port). With $RAVENMEM_MILVUS_REQUIRED=1 (as CI sets it) a missing
server fails the tests instead of skipping them, so that CI cannot pass without running them.
"""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from tests.store.store_helpers import BACKENDS, StoreOpener, opener, port_open


def _no_server(reason: str) -> None:
    if os.environ.get("RAVENMEM_MILVUS_REQUIRED") == "1":
        pytest.fail(f"RAVENMEM_MILVUS_REQUIRED=1 but {reason}")
    pytest.skip(reason)


@pytest.fixture(scope="session")
def milvus_server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    """host:port of a Milvus server, started here from the `milvus` PyPI package's script."""
    if os.environ.get("RAVENMEM_MILVUS_REQUIRED") != "1":
        pytest.importorskip("pymilvus")
    uri = os.environ.get("RAVENMEM_MILVUS_URI")
    if uri:
        yield uri
        return
    binary = os.environ.get("RAVENMEM_MILVUS_SERVER") or shutil.which("milvus-server")
    if not binary:
        _no_server(
            "no Milvus server: pip install milvus (2.3.x) and put milvus-server on PATH or in $RAVENMEM_MILVUS_SERVER"
        )
    if port_open("127.0.0.1", 19530):
        _no_server("port 19530 is taken; set RAVENMEM_MILVUS_URI=127.0.0.1:19530 to test against that server")
    data = tmp_path_factory.mktemp("milvus-server")
    with open(data / "server.log", "wb") as log:
        # own process group: the script starts the real server as a child that outlives it
        cmd = [binary, "--data", str(data)]
        proc = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
        try:
            deadline = time.time() + 180
            while not port_open("127.0.0.1", 19530):
                if proc.poll() is not None or time.time() > deadline:
                    tail = (data / "server.log").read_text(errors="replace")[-1500:]
                    pytest.fail(f"milvus-server did not start in 180 s (see {data / 'server.log'}):\n{tail}")
                time.sleep(1)
            time.sleep(3)  # the proxy listens before the coordinators are ready
            yield "127.0.0.1:19530"
        finally:  # a throw-away server in a temp folder: no need for its slow graceful stop
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait(30)


@pytest.fixture(params=BACKENDS)
def open_fn(request: pytest.FixtureRequest, tmp_path: Path) -> StoreOpener:
    return opener(request.param, tmp_path, request)
