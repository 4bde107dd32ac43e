"""`ravenmem serve` on a memory of real TUM frames with the offline embedder (slow: it loads the
models twice, here and in the service): the service and the CLI's `--server` answer as a local
run does. The same paths with the instant test embedder run in the default suite
(test_cli_server.py, test_live.py)."""

from __future__ import annotations

import json
import time
from collections.abc import Iterator
from functools import partial
from pathlib import Path

import httpx
import pytest

from tests.cli.helpers import run_cli

REPO = Path(__file__).resolve().parents[2]
pytestmark = pytest.mark.slow


rm = partial(run_cli, timeout=600, unset=("RAVENMEM_SERVER", "RAVENMEM_TOKEN"))


@pytest.fixture(scope="module")
def embedder():
    from ravenmem.embed.base import create_embedder

    return create_embedder("offline")


@pytest.fixture(scope="module")
def desk(tmp_path_factory, embedder) -> Path:
    import ravenmem
    from ravenmem.ingest.keyframes import KeyframeConfig
    from ravenmem.ingest.pipeline import ingest
    from ravenmem.ingest.sources import open_source
    from tests.conftest import tum_data

    TUM = tum_data()
    path = tmp_path_factory.mktemp("serve") / "desk.mem"
    with ravenmem.create(path, embedder=embedder, ocr=False) as mem:
        ingest(open_source(str(TUM), "tum"), mem, KeyframeConfig.only(stride=30), progress=False)
        assert mem.count() == 24
    return path


def local(desk: Path, embedder):
    import ravenmem

    return ravenmem.open(desk, embedder=embedder)


@pytest.fixture(scope="module")
def service(desk: Path) -> Iterator[str]:
    from tests.server.conftest import serve_subprocess, stop

    proc, url = serve_subprocess(desk, colour=False)
    # models are loaded before the port answers: the first request is already warm
    assert httpx.get(url + "/search/text", params={"q": "a keyboard", "k": 1}, timeout=60).status_code == 200
    yield url
    stop(proc)


def strip_images(rows: list[dict]) -> list[dict]:
    return [{k: v for k, v in r.items() if k != "image"} for r in rows]


def test_search_via_the_service_matches_a_local_run(desk: Path, embedder, service: str):
    from ravenmem.tools import TOOLS, hit_json

    remote = rm("search", "a computer keyboard", "--server", service, "-k", "5", "--json")
    assert remote.returncode == 0, remote.stderr
    b = json.loads(remote.stdout)
    assert (b["mode"], b["tool"]) == ("text", "search_text")
    with local(desk, embedder) as mem:
        hits = TOOLS["search_text"].run(mem, {"query": "a computer keyboard"}, 5)
        t0 = mem.time_span()[0]
        a = [hit_json(h, i + 1, t0) for i, h in enumerate(hits)]
        thumb = mem.image_file(hits[0].memory)
    assert strip_images(a) == strip_images(b["results"])
    assert b["results"][0]["image"] == f"{service}/memories/{b['results'][0]['id']}/image"
    assert thumb is not None and httpx.get(b["results"][0]["image"]).content == thumb.read_bytes()


def test_the_other_tools_and_the_environment_variable(desk: Path, service: str):
    env = {"RAVENMEM_SERVER": service}
    when = rm("search", "--time", "00:00:12", "-k", "4", "--json", env=env)
    assert when.returncode == 0, when.stderr
    times = [x["offset_s"] for x in json.loads(when.stdout)["results"]]
    assert len(times) == 4 and times == sorted(times) and 11.5 <= times[0] <= 13.5
    where = rm("search", "--position", "1.3,0.6,1.6", "-k", "3", "--radius", "1", "--json", env=env)
    d = [x["distance"] for x in json.loads(where.stdout)["results"]]
    assert d == sorted(d) and d[0] < 0.1
    first = json.loads(where.stdout)["results"][0]
    like = rm("search", "--like", str(first["id"]), "-k", "2", "--near", "1.3,0.6,5", "--json", env=env)
    assert like.returncode == 0 and first["id"] not in [x["id"] for x in json.loads(like.stdout)["results"]]
    # a picture uploaded from this machine: the frame itself comes back first
    from tests.conftest import TUM

    frame = sorted((TUM / "rgb").glob("*.jpg"))[0]
    up = rm("search", "--image", str(frame), "-k", "1", "--json", env=env)
    assert up.returncode == 0, up.stderr
    assert json.loads(up.stdout)["results"][0]["score"] > 0.9
    table = rm("search", "a monitor", "-k", "2", env=env)
    assert table.returncode == 0 and f"{service}/memories/" in table.stdout  # URLs shown as they are


def test_info_and_ask_via_the_service(desk: Path, embedder, service: str):
    from ravenmem.agent.methods import create_method

    remote = json.loads(rm("info", "--server", service, "--json").stdout)
    q = "where is the keyboard?"
    b = rm("ask", q, "--server", service, "--offline", "--json")
    assert b.returncode in (0, 1), b.stderr
    with local(desk, embedder) as mem:
        info = mem.info()
        la = create_method("offline", mem).ask(q).model_dump(mode="json")
    for key in ("memories", "embedder", "dim", "t_min", "t_max", "frames_seen", "store"):
        assert info[key] == remote[key], key
    assert remote["path"] == "desk.mem" and remote["ask"]["default_method"] == "offline"
    ra = json.loads(b.stdout)
    for key in ("text", "position", "yaw", "found", "question_type", "method", "time"):
        assert la[key] == ra[key], key
    assert [e["id"] for e in la["evidence"]] == [e["id"] for e in ra["evidence"]]
    assert all(e["image_file"].startswith(service) for e in ra["evidence"])
    shown = rm("ask", q, "--server", service, "--offline")
    assert "answer:" in shown.stdout and "evidence memories" in shown.stdout


def test_live_add_of_a_real_frame(service: str):
    from tests.conftest import TUM

    frame = sorted((TUM / "rgb").glob("*.jpg"))[400]
    with httpx.Client(base_url=service, timeout=60) as c:
        r = c.post(
            "/memories",
            files={"image": (frame.name, frame.read_bytes(), "image/jpeg")},
            data={"x": "9", "y": "9", "z": "1", "yaw": "0.5", "t": str(time.time())},
        )
        assert r.status_code == 201, r.text
        new = r.json()["id"]
        top = c.post(
            "/search/image", params={"k": 1}, files={"image": (frame.name, frame.read_bytes(), "image/jpeg")}
        )
        assert top.json()["results"][0]["id"] == new
        assert c.get("/health").json()["memories"] == 25
