"""`ravenmem search/ask/info --server URL`: a running service answers as a local run does.

The service is the real `ravenmem serve` in a subprocess (colour test embedder: instant); the
CLI runs as users run it, in its own process, and opens no memory and loads no model. The many
short command lines of the tool and error tables are forked by one driver (`ForkedCli`: the
real entry point, exit code and streams); a search, info and ask start a fresh interpreter."""

from __future__ import annotations

import json
import signal
import subprocess
from collections.abc import Iterator
from functools import partial
from pathlib import Path

import httpx
import pytest
from PIL import Image

import ravenmem
from ravenmem.agent.methods import create_method
from ravenmem.agent.support import judged
from ravenmem.tools import TOOLS, hit_json
from tests.agent.conftest import T0
from tests.cli.helpers import ForkedCli, run_cli
from tests.conftest import ColorEmbedder
from tests.server.conftest import make_memory, running_service, serve_subprocess

UNSET = ("RAVENMEM_SERVER", "RAVENMEM_TOKEN")
rm = partial(run_cli, timeout=300, unset=UNSET)


@pytest.fixture(scope="module")
def scene(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("cli-server") / "scene.mem"
    make_memory(path).close()
    return path


@pytest.fixture(scope="module")
def service(scene: Path) -> Iterator[str]:
    yield from running_service(scene, "--read-only")


def local(scene: Path) -> ravenmem.Memory:
    return ravenmem.open(scene, embedder=ColorEmbedder())


def no_images(rows: list[dict]) -> list[dict]:
    return [{k: v for k, v in r.items() if k != "image"} for r in rows]


def test_search_matches_a_local_run(scene: Path, service: str):
    r = rm("search", "something blue", "--server", service, "-k", "4", "--after", "+25s", "--json")
    assert r.returncode == 0, r.stderr
    remote = json.loads(r.stdout)
    with local(scene) as mem:
        hits = TOOLS["search_text"].run(mem, {"query": "something blue", "after": "+25s"}, 4)
        hits = judged(mem, "something blue", hits)  # the verdict the service adds to text hits
        rows = [hit_json(h, i + 1, mem.time_span()[0]) for i, h in enumerate(hits)]
        thumb = mem.image_file(hits[0].memory)
    assert (remote["mode"], remote["tool"]) == ("text", "search_text")
    assert no_images(remote["results"]) == no_images(rows)
    first = remote["results"][0]
    assert first["image"] == f"{service}/memories/{first['id']}/image"
    assert thumb is not None and httpx.get(first["image"]).content == thumb.read_bytes()


def test_every_tool_through_the_service(scene: Path, service: str, tmp_path: Path, forked_cli: ForkedCli):
    rm = partial(forked_cli, timeout=300, unset=UNSET)
    env = {"RAVENMEM_SERVER": service}  # no --memory: the environment names the service
    when = json.loads(rm("search", "--time", "+20s", "-k", "3", "--json", env=env).stdout)["results"]
    assert [x["offset_s"] for x in when] == [20.0, 30.0, 40.0]
    where = json.loads(
        rm("search", "--position", "3,1", "-k", "2", "--radius", "1.5", "--json", env=env).stdout
    )
    assert where["results"][0]["id"] == 4 and where["results"][0]["distance"] == 0.0
    like = json.loads(rm("search", "--like", "4", "-k", "2", "--json", env=env).stdout)["results"]
    assert {x["id"] for x in like} == {7, 11}
    near = json.loads(rm("search", "blue", "--near", "6,2,1.5", "-k", "1", "--json", env=env).stdout)[
        "results"
    ]
    assert [x["id"] for x in near] == [7]
    pic = tmp_path / "yellow.png"
    Image.new("RGB", (20, 20), (255, 255, 0)).save(pic)
    up = rm("search", "--image", str(pic), "-k", "1", "--json", env=env)
    assert up.returncode == 0, up.stderr
    assert json.loads(up.stdout)["results"][0]["id"] == 3
    table = rm("search", "red", "-k", "2", env=env)
    assert table.returncode == 0 and f"{service}/memories/" in table.stdout  # URLs shown whole
    explicit = rm("search", "red", "-k", "2", "--memory", str(scene), "--json", env=env)
    assert (
        explicit.returncode == 2 and "unknown embedder 'test-color'" in explicit.stderr
    )  # --memory wins: local


def test_info_and_ask_through_the_service(scene: Path, service: str):
    info = rm("info", "--server", service, "--json")
    assert info.returncode == 0, info.stderr
    remote = json.loads(info.stdout)
    with local(scene) as mem:
        here = mem.info()
        answer = create_method("offline", mem).ask("where is the cyan box?").model_dump(mode="json")
    for key in ("memories", "embedder", "dim", "t_min", "t_max", "thumb_size"):
        assert remote[key] == here[key], key
    assert remote["path"] == "scene.mem" and remote["live"] is None  # --read-only
    shown = rm("info", "--server", service)
    assert "memories  12" in shown.stdout and "ask  default method offline" in shown.stdout
    r = rm("ask", "where is the cyan box?", "--server", service, "--offline", "--json")
    assert r.returncode == 0, r.stderr
    a = json.loads(r.stdout)
    for key in ("text", "position", "yaw", "found", "question_type", "method", "time"):
        assert a[key] == answer[key], key
    assert [e["id"] for e in a["evidence"]] == [e["id"] for e in answer["evidence"]]
    assert a["evidence"][0]["image_file"] == f"{service}/memories/6/image"
    table = rm("ask", "where is the cyan box?", "--server", service, "--offline")
    assert (
        "answer:" in table.stdout and "x=5.00, y=2.00" in table.stdout and "evidence memories" in table.stdout
    )


def test_errors_through_the_service_are_one_line(scene: Path, service: str, forked_cli: ForkedCli):
    rm = partial(forked_cli, timeout=300, unset=UNSET)

    def one_line(r: subprocess.CompletedProcess[str]) -> str:
        assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr
        assert len(r.stderr.strip().splitlines()) == 1, r.stderr
        return r.stderr

    assert "not both" in one_line(rm("search", "red", "--memory", str(scene), "--server", service))
    assert "--server" in one_line(rm("info"))
    assert "cannot reach" in one_line(rm("info", "--server", "http://127.0.0.1:9"))
    assert "http://" in one_line(rm("info", "--server", "ftp://example.com"))
    bad = one_line(rm("search", "red", "--after", "the day after never", "--server", service))
    assert bad.startswith("error: service http://127.0.0.1:") and "time" in bad
    assert "VLM settings" in one_line(rm("ask", "where?", "--server", service, "--model", "gpt-x"))
    assert "needs a VLM" in one_line(rm("ask", "where?", "--server", service, "--method", "raven"))
    assert "--k: expected" in one_line(rm("search", "red", "-k", "0", "--server", service))


def test_token_from_the_environment(tmp_path):
    from tests.server.conftest import TOKEN

    path = tmp_path / "scene.mem"
    make_memory(path).close()
    proc, url = serve_subprocess(path, "--token", TOKEN, health_token=TOKEN)
    try:
        refused = rm("info", "--server", url)
        assert refused.returncode == 2 and "bearer token" in refused.stderr
        ok = rm(
            "search",
            "--time",
            f"{T0 + 10}",
            "-k",
            "1",
            "--server",
            url,
            "--json",
            env={"RAVENMEM_TOKEN": TOKEN},
        )
        assert ok.returncode == 0, ok.stderr
        assert json.loads(ok.stdout)["results"][0]["id"] == 2
    finally:
        proc.send_signal(signal.SIGINT)
        proc.wait(60)
