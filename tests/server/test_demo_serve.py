"""The issue's done-when: the memory the README's first command (`ravenmem demo`) builds can be
served. The demo runs on the synthetic world with the colour test embedder (seconds, not the
minutes of the Freedoom maps); the service is the real `ravenmem serve` in a subprocess."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import httpx

from ravenmem.demo import DemoConfig, run_demo
from tests.conftest import ColorEmbedder
from tests.server.conftest import REPO, serve_subprocess


def test_the_demo_says_how_to_serve_its_memory_and_serve_opens_it(tmp_path: Path) -> None:
    cfg = DemoConfig(
        maps=["synthetic:rooms"],
        out=str(tmp_path / "demo"),
        steps=200,
        embedder=ColorEmbedder(),
        text_method="embedder-only",
        keyframe_dist=1.0,
        keyframe_turn=0.5,
    )
    rep = run_demo(cfg)
    m = re.search(r"ravenmem serve --memory (\S+)", rep.table())
    assert m is not None, rep.table()
    memory = Path(m.group(1))
    assert memory == tmp_path / "demo" / "rooms" / "memory"

    proc, url = serve_subprocess(memory)
    try:
        assert httpx.get(url + "/health").json() == {"status": "ok", "memories": rep.maps[0].memories}
        assert httpx.get(url + "/map").status_code == 200  # the demo's occupancy map, on the page
        hits = httpx.get(url + "/search/text", params={"q": "red box", "k": 3}).json()["results"]
        assert len(hits) == 3 and httpx.get(hits[0]["image"]).headers["content-type"] == "image/jpeg"
    finally:
        proc.terminate()
        proc.wait(timeout=30)

    # the demo's output folder itself is not a memory: said so, not "does not exist"
    r = subprocess.run(
        [
            sys.executable,
            "-m",
            "ravenmem.cli.main",
            "serve",
            "--memory",
            str(tmp_path / "demo"),
            "--port",
            "0",
        ],
        capture_output=True,
        text=True,
        env={"PYTHONPATH": str(REPO / "src"), "PATH": "/usr/bin:/bin"},
        timeout=120,
    )
    assert (
        r.returncode == 2
        and r.stderr.strip() == f"error: {tmp_path / 'demo'} is not a memory (no memory.json in it)"
    )
