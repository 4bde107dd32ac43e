"""Every route over real HTTP against a real uvicorn server: shapes, order, errors, bounds."""

from __future__ import annotations

import base64
import io
import json

import httpx
import numpy as np
import pytest
from PIL import Image

from ravenmem.agent import VLMConfig
from ravenmem.memory.protocol import MAX_K
from ravenmem.tools import TOOLS
from tests.agent.conftest import SCENE, T0
from tests.agent.scripted_server import ScriptedModel, answer, tool
from tests.server.conftest import Served, serve_memory

HIT_KEYS = {
    "rank",
    "id",
    "score",
    "distance",
    "t",
    "time",
    "offset_s",
    "x",
    "y",
    "z",
    "yaw",
    "yaw_deg",
    "image",
    "source",
    "frame_index",
    "ocr_text",
    "ocr_match",
    "supported",
}


def png(color: tuple[int, int, int], size: tuple[int, int] = (40, 30), fmt: str = "PNG") -> bytes:
    buf = io.BytesIO()
    Image.new("RGB", size, color).save(buf, fmt)
    return buf.getvalue()


def one_line_error(r: httpx.Response) -> str:
    body = r.json()
    assert set(body) == {"error"}, body
    assert "\n" not in body["error"] and "Traceback" not in r.text and len(body["error"]) < 400
    return str(body["error"])


def test_health_and_info(served: Served):
    with served.client() as c:
        assert c.get("/health").json() == {"status": "ok", "memories": len(SCENE)}
        info = c.get("/info").json()
    assert info["memories"] == len(SCENE) and info["embedder"] == "test-color"
    assert info["path"] == "scene.mem"  # the folder's name, not where it lies on the server
    assert info["t_min"] == T0 and info["live"] == {"frames_seen": 0, "kept": 0, "skipped": {}}
    assert info["ask"]["default_method"] == "offline" and "raven" in info["ask"]["methods"]


def test_text_search_is_the_cli_json_with_image_urls(served: Served):
    with served.client() as c:
        r = c.get("/search/text", params={"q": "red", "k": 3})
        assert r.status_code == 200, r.text
        body = r.json()
        assert body["mode"] == "text" and body["tool"] == "search_text"
        rows = body["results"]
        assert [row["rank"] for row in rows] == [1, 2, 3]
        assert set(rows[0]) == HIT_KEYS
        # the two red memories (ids 2 and 9) come first, best first
        assert {rows[0]["id"], rows[1]["id"]} == {2, 9} and rows[0]["score"] >= rows[1]["score"] >= rows[2][
            "score"
        ]
        assert rows[0]["image"] == f"{served.url}/memories/{rows[0]['id']}/image"
        img = c.get(rows[0]["image"])
        assert img.status_code == 200 and img.headers["content-type"] == "image/jpeg"
        arr = np.asarray(Image.open(io.BytesIO(img.content)))
        assert arr[..., 0].mean() > 200 and arr[..., 1].mean() < 60  # it is the red picture
        # the long name, and the same memories as in-process
        same = c.get("/search/text", params={"query": "red", "k": 3}).json()
    assert same == body
    local = [h.memory.id for h in served.mem.search_text("red", k=3)]
    assert [row["id"] for row in rows] == local


def test_text_hits_carry_the_verdict_ask_declines_by(served: Served):
    """A colour the scene holds is supported; a word the colour embedder cannot tell from the
    decoys (things that are not there) is not; the other tools do not judge (null)."""
    with served.client() as c:
        red = c.get("/search/text", params={"q": "red", "k": 3}).json()["results"]
        smell = c.get("/search/text", params={"q": "a smell of toast", "k": 3}).json()["results"]
        when = c.get("/search/time", params={"t": "+20s", "k": 2}).json()["results"]
    assert [r["supported"] for r in red[:2]] == [True, True] and {r["id"] for r in red[:2]} == {2, 9}
    assert len(smell) == 3 and [r["supported"] for r in smell] == [False, False, False]
    assert [r["supported"] for r in when] == [None, None]
    # the rule is the offline reasoner's: it declines the same thing
    with served.client() as c:
        answer = c.post("/ask", json={"question": "where is a smell of toast?", "method": "offline"}).json()
    assert answer["found"] is False


def test_filters_reach_the_tools(served: Served):
    with served.client() as c:
        near = c.get("/search/text", params={"q": "blue", "k": 5, "near": "6,2,1.5"}).json()["results"]
        assert [r["id"] for r in near][:1] == [7] and all(
            abs(r["x"] - 6) ** 2 + (r["y"] - 2) ** 2 <= 2.25 for r in near
        )
        rep = c.get("/search/text", params=[("q", "blue"), ("near", 6), ("near", 2), ("near", 1.5)]).json()
        assert rep["results"] == near
        after = c.get("/search/text", params={"q": "blue", "k": 5, "after": "+55s"}).json()["results"]
        assert after and all(r["t"] >= T0 + 55 for r in after)
        before = c.get("/search/text", params={"q": "blue", "k": 5, "before": "+35s"}).json()["results"]
        assert [r["id"] for r in before] != [] and all(r["t"] <= T0 + 35 for r in before)


def test_time_position_and_image_by_id(served: Served):
    with served.client() as c:
        times = c.get("/search/time", params={"t": "+20s", "k": 3}).json()
        assert times["tool"] == "search_time"
        assert [r["offset_s"] for r in times["results"]] == [20.0, 30.0, 40.0]
        pos = c.get("/search/position", params={"x": 3, "y": 1, "k": 3, "radius": 2}).json()["results"]
        assert pos[0]["id"] == 4 and pos[0]["distance"] == pytest.approx(0.0)
        assert [r["distance"] for r in pos] == sorted(r["distance"] for r in pos) and all(
            r["distance"] <= 2 for r in pos
        )
        like = c.get("/search/image", params={"memory_id": 4, "k": 2}).json()["results"]
        assert {r["id"] for r in like} == {7, 11}  # the other two blue memories, not memory 4 itself


def test_image_upload_search(served: Served):
    with served.client() as c:
        r = c.post(
            "/search/image", params={"k": 2}, files={"image": ("q.png", png((255, 255, 0)), "image/png")}
        )
        assert r.status_code == 200, r.text
        assert r.json()["results"][0]["id"] == 3  # the yellow memory
        both = c.post(
            "/search/image", params={"memory_id": 1}, files={"image": ("q.png", png((0, 0, 0)), "image/png")}
        )
        assert both.status_code == 400 and "not both" in one_line_error(both)


def test_memory_record_and_trajectory(served: Served):
    with served.client() as c:
        rec = c.get("/memories/4").json()
        assert rec["id"] == 4 and rec["x"] == 3.0 and rec["image"].endswith("/memories/4/image")
        assert "rank" not in rec and "score" not in rec
        traj = c.get("/trajectory").json()
        assert traj["count"] == len(SCENE) and [p[0] for p in traj["points"]] == list(range(1, 13))
        thin = c.get("/trajectory", params={"max_points": 4}).json()
        assert len(thin["points"]) <= 5 and thin["points"][-1][0] == 12


@pytest.mark.parametrize(
    ("path", "params", "status", "words"),
    [
        ("/search/text", {"q": "red", "k": MAX_K + 1}, 422, "k"),
        ("/search/text", {"q": "red", "k": 0}, 422, "k"),
        ("/search/text", {"q": "red", "k": "many"}, 422, "k"),
        ("/search/text", {"k": 3}, 422, "query"),
        ("/search/text", {"q": "x" * 1001}, 422, "query"),
        ("/search/text", {"q": "   "}, 422, "blank"),
        ("/search/text", {"q": "red", "bogus": 1}, 422, "bogus"),
        ("/search/text", {"q": "red", "near": "1,2"}, 422, "near"),
        ("/search/text", {"q": "red", "after": "the day after never"}, 400, "time"),
        ("/search/position", {"x": "nan", "y": 1}, 422, "x"),
        ("/search/position", {"x": 1, "y": 1, "radius": -2}, 422, "radius"),
        ("/search/image", {"memory_id": 999}, 404, "999"),  # an id not stored, as /memories/999
        ("/search/image", {}, 400, "memory_id"),
        ("/search/time", {}, 422, "time"),
        ("/memories/999", {}, 404, "999"),
        ("/memories/abc", {}, 422, "memory_id"),
        ("/memories/999/image", {}, 404, "999"),
        ("/trajectory", {"max_points": 1}, 422, "max_points"),
        ("/nowhere", {}, 404, "Not Found"),
    ],
)
def test_bad_requests_get_a_one_line_4xx(served: Served, path, params, status, words):
    with served.client() as c:
        r = c.get(path, params=params)
    assert r.status_code == status, r.text
    assert words.lower() in one_line_error(r).lower()


def test_every_tool_has_a_route_with_its_arguments_documented(served: Served):
    with served.client() as c:
        spec = c.get("/openapi.json").json()
    for t in TOOLS.values():
        op = spec["paths"][f"/search/{t.key}"]["get"]
        names = {p["name"] for p in op["parameters"]}
        assert names == set(t.args.model_fields) | {"k"}, t.name
    assert "post" in spec["paths"]["/search/image"] and "post" in spec["paths"]["/memories"]


def test_ask_offline_and_its_event(served: Served):
    with served.client() as c:
        r = c.post("/ask", json={"question": "where is the yellow thing?", "method": "embedder-only"})
        assert r.status_code == 200, r.text
        a = r.json()
    assert a["method"] == "embedder-only" and a["found"] and a["position"][:2] == [2.0, 0.0]
    ev = a["evidence"][0]
    assert ev["id"] == 3 and ev["image"].endswith("/memories/3/image") and "image_path" not in ev


def test_ask_rejects_what_it_cannot_do(served: Served):
    with served.client() as c:
        r = c.post("/ask", json={"question": "where is it?", "method": "raven"})
        assert r.status_code == 400 and "needs a VLM" in one_line_error(r)
        r = c.post("/ask", json={"question": "where?", "method": "telepathy"})
        assert r.status_code == 400 and "telepathy" in one_line_error(r)
        r = c.post("/ask", json={"question": "", "method": "offline"})
        assert r.status_code == 422
        r = c.post("/ask", json={"question": "q", "base_url": "http://evil.example/v1"})
        assert r.status_code == 422 and "base_url" in one_line_error(r)  # no caller-chosen endpoints
        r = c.post("/ask", content=b"{not json", headers={"content-type": "application/json"})
        assert r.status_code == 422 and one_line_error(r)
        r = c.post("/ask", json={"question": "where?", "image": "!!notbase64!!"})
        assert r.status_code == 400 and "base64" in one_line_error(r)


def test_ask_with_an_image_as_base64(served: Served):
    b64 = "data:image/png;base64," + base64.b64encode(png((0, 255, 255))).decode()
    with served.client() as c:
        r = c.post(
            "/ask", json={"question": "where did I see this?", "method": "embedder-only", "image": b64}
        )
        assert r.status_code == 200, r.text
        by_id = c.post(
            "/ask",
            json={"question": "where did I see this?", "method": "embedder-only", "image_memory_id": 6},
        )
    assert r.json()["evidence"][0]["id"] == 6  # the cyan memory
    assert by_id.status_code == 200 and by_id.json()["evidence"][0]["id"] == 6


def test_ask_raven_uses_the_services_own_vlm(tmp_path):
    from tests.server.conftest import make_memory

    script = [
        tool("search_text", query="magenta"),
        answer(question_type="position", answer="by the door", evidence=[8]),
    ]
    with ScriptedModel(script) as vlm:
        cfg = VLMConfig(base_url=vlm.base_url, model="scripted", api_key="k", timeout=5, max_retries=0)
        for s in serve_memory(make_memory(tmp_path / "m.mem"), vlm=cfg):
            with s.client() as c:
                assert c.get("/info").json()["ask"]["default_method"] == "raven"
                r = c.post(
                    "/ask",
                    json={
                        "question": "where is the magenta box?",
                        "preset": "findingdory",
                        "top_k": {"text": 2},
                    },
                )
            assert r.status_code == 200, r.text
            a = r.json()
            assert a["method"] == "raven" and a["text"] == "by the door" and a["position"][:2] == [7.0, 3.0]
            assert a["preset"] == "findingdory" and a["evidence"][0]["image"].endswith("/memories/8/image")
        assert len(vlm.requests) == 2 and "search_text" in vlm.tool_names(0)
        shown = [m for m in vlm.requests[1]["messages"] if m["role"] == "tool"][0]["content"]
        assert "-> 2 memories" in shown and "[m8]" in shown  # top_k {text: 2} overrides the preset's 30


@pytest.mark.parametrize(
    ("body", "words"),
    [
        ({"question": "where?", "preset": "bogus"}, "unknown preset"),
        ({"question": "where?", "top_k": {"text": 0}}, "k must be"),
        ({"question": "where?", "top_k": {t: 1 for t in "abcde"}}, "up to 4 tools"),
        ({"question": "where?", "max_tool_calls": 99}, "max_tool_calls"),
    ],
)
def test_ask_settings_are_checked(served: Served, body, words):
    with served.client() as c:
        r = c.post("/ask", json={**body, "method": "offline"})
    assert r.status_code in (400, 422) and words in one_line_error(r)


def test_add_memory_live(served: Served):
    with served.client() as c:
        r = c.post(
            "/memories",
            files={"image": ("f.jpg", png((255, 0, 0), fmt="JPEG"), "image/jpeg")},
            data={"x": "12", "y": "5", "z": "0.5", "yaw": "1.5", "t": str(T0 + 500), "source": "front"},
        )
        assert r.status_code == 201, r.text
        body = r.json()
        assert body["stored"] and body["id"] == 13 and body["skipped"] is None
        m = body["memory"]
        assert (m["x"], m["y"], m["yaw"], m["source"], m["t"]) == (12.0, 5.0, 1.5, "front", T0 + 500)
        assert c.get(m["image"]).status_code == 200
        hits = c.get("/search/position", params={"x": 12, "y": 5, "k": 1}).json()["results"]
        assert hits[0]["id"] == 13
        q = c.post(
            "/memories",
            files={"image": ("f.png", png((0, 0, 255)), "image/png")},
            data={"x": "1", "y": "1", "qx": "0", "qy": "0", "qz": "0.7071068", "qw": "0.7071068"},
        )
        assert q.status_code == 201 and q.json()["memory"]["yaw"] == pytest.approx(np.pi / 2, abs=1e-6)
        # older than the last frame of this source: the ingest pipeline's rule
        old = c.post(
            "/memories",
            files={"image": ("f.png", png((0, 255, 0)), "image/png")},
            data={"x": "1", "y": "1", "t": str(T0 + 400), "source": "front"},
        )
        assert old.status_code == 200 and old.json() == {
            "stored": False,
            "id": None,
            "skipped": "non-monotonic timestamp",
            "t": T0 + 400,
            "source": "front",
        }
        assert c.get("/info").json()["live"] == {
            "frames_seen": 3,
            "kept": 2,
            "skipped": {"non-monotonic timestamp": 1},
        }
    assert served.mem.count() == len(SCENE) + 2


def test_live_adds_follow_the_keyframe_rule(tmp_path):
    from ravenmem.ingest.keyframes import KeyframeConfig
    from tests.server.conftest import make_memory

    kf = KeyframeConfig.from_spec("min_translation=1.0,max_similarity=0.99")
    for s in serve_memory(make_memory(tmp_path / "m.mem"), keyframes=kf):
        outcomes = []
        with s.client() as c:
            for i, (x, colour) in enumerate(
                [(0, (255, 0, 0)), (0.2, (0, 0, 255)), (2, (255, 0, 0)), (4, (0, 0, 255))]
            ):
                r = c.post(
                    "/memories",
                    files={"image": ("f.png", png(colour), "image/png")},
                    data={"x": str(x), "y": "0", "t": str(T0 + 1000 + i)},
                )
                outcomes.append(r.json()["skipped"] or "stored")
        # moved 0.2 m: too little; moved 2 m but looks like the last kept (red): similar
        assert outcomes == ["stored", "too little motion", "similar to last keyframe", "stored"]


@pytest.mark.parametrize(
    ("files", "data", "status", "words"),
    [
        ({"image": ("f.png", b"not an image", "image/png")}, {"x": "1", "y": "1"}, 400, "JPEG or PNG"),
        ({"image": ("f.gif", b"GIF89a" + b"\0" * 20, "image/gif")}, {"x": "1", "y": "1"}, 400, "JPEG or PNG"),
        ({"image": ("f.png", png((1, 2, 3)), "image/png")}, {"y": "1"}, 422, "x"),
        ({"image": ("f.png", png((1, 2, 3)), "image/png")}, {"x": "inf", "y": "1"}, 400, "pose"),
        ({"image": ("f.png", png((1, 2, 3)), "image/png")}, {"x": "1", "y": "1", "qx": "0"}, 400, "qx"),
        (
            {"image": ("f.png", png((1, 2, 3)), "image/png")},
            {"x": "1", "y": "1", "t": "nan"},
            400,
            "t: nan is not",
        ),
        ({}, {"x": "1", "y": "1"}, 422, "image"),
    ],
)
def test_bad_adds_get_a_one_line_4xx_and_store_nothing(served: Served, files, data, status, words):
    with served.client() as c:
        r = c.post("/memories", files=files or None, data=data)
        assert r.status_code == status, r.text
        assert words.lower() in one_line_error(r).lower()
    assert served.mem.count() == len(SCENE)


def test_request_sizes_are_bounded(tmp_path):
    from tests.server.conftest import make_memory

    for s in serve_memory(make_memory(tmp_path / "m.mem"), max_upload_bytes=200_000, max_pixels=10_000):
        with s.client() as c:
            big = c.post(
                "/memories",
                files={"image": ("f.png", b"\0" * 300_000, "image/png")},
                data={"x": "1", "y": "1"},
            )
            assert big.status_code == 413 and "limit" in one_line_error(big)

            def chunks():
                yield b'{"question": "'
                yield b"a" * 300_000
                yield b'"}'

            chunked = c.post("/ask", content=chunks(), headers={"content-type": "application/json"})
            assert chunked.status_code == 413 and "limit" in one_line_error(chunked)
            many = c.post(
                "/memories",
                files={"image": ("f.png", png((0, 0, 0), (200, 200)), "image/png")},
                data={"x": "1", "y": "1"},
            )
            assert many.status_code == 413 and "pixels" in one_line_error(many)
        assert s.mem.count() == len(SCENE)


def test_events_stream_new_memories_skips_and_answers(served: Served):
    import threading

    got: list[tuple[str, dict]] = []
    ready = threading.Event()

    def listen():
        with httpx.Client(base_url=served.url, timeout=30) as c, c.stream("GET", "/events") as r:
            assert r.headers["content-type"].startswith("text/event-stream")
            kind = None
            for line in r.iter_lines():
                if line.startswith("event: "):
                    kind = line[7:]
                elif line.startswith("data: "):
                    got.append((kind, json.loads(line[6:])))
                    if kind == "hello":
                        ready.set()
                    if kind == "answer":
                        return

    th = threading.Thread(target=listen, daemon=True)
    th.start()
    assert ready.wait(20)
    with served.client() as c:
        added = c.post(
            "/memories",
            files={"image": ("f.png", png((255, 0, 255)), "image/png")},
            data={"x": "20", "y": "1", "t": str(T0 + 900)},
        ).json()
        c.post(
            "/memories",
            files={"image": ("f.png", png((255, 0, 255)), "image/png")},
            data={"x": "20", "y": "1", "t": str(T0 + 800)},
        )
        c.post("/ask", json={"question": "where is the cyan thing?", "method": "embedder-only"})
    th.join(20)
    kinds = [k for k, _ in got]
    assert kinds == ["hello", "memory", "skipped", "answer"], got
    assert got[0][1]["memories"] == len(SCENE)
    assert (
        got[1][1]["memory"]["id"] == added["id"]
        and got[1][1]["memory"]["image"] == f"/memories/{added['id']}/image"
    )
    assert got[2][1]["skipped"] == "non-monotonic timestamp"
    assert got[3][1]["answer"]["question"] == "where is the cyan thing?"
    seqs = [d["seq"] for _, d in got[1:]]
    assert seqs == sorted(seqs)


def test_the_page_and_its_files_are_served(served: Served):
    with served.client() as c:
        page = c.get("/")
        assert page.status_code == 200 and "text/html" in page.headers["content-type"]
        assert '<script src="/static/app.js">' in page.text
        js = c.get("/static/app.js")
        assert js.status_code == 200 and "function draw()" in js.text
        assert "http" not in c.get("/static/app.js").text.replace("http://www.w3.org/2000/svg", "")  # no CDN
        assert c.get("/static/../memory.json").status_code == 404
        assert c.get("/static/%2e%2e/memory.json").status_code == 404
        docs = c.get("/docs")
        assert docs.status_code == 200


def test_api_docs_load_their_scripts_from_the_service_when_fastapi_offline_is_there(served: Served):
    """A robot without internet still gets a working /docs: Swagger UI's own files come from the
    service (fastapi-offline, the api-docs extra); without it FastAPI's CDN page is the fallback."""
    pytest.importorskip("fastapi_offline", reason="the api-docs extra: pip install 'ravenmem[api-docs]'")
    with served.client() as c:
        for page in ("/docs", "/redoc"):
            html = c.get(page)
            assert html.status_code == 200
            assert "cdn" not in html.text.lower() and "/docs-static/" in html.text
        for asset in ("swagger-ui-bundle.js", "swagger-ui.css", "redoc.standalone.js"):
            r = c.get(f"/docs-static/{asset}")
            assert r.status_code == 200 and len(r.content) > 100_000
        assert c.get("/docs-static/../memory.json").status_code == 404


def test_a_body_announced_over_the_limit_is_refused_before_it_is_sent(tmp_path):
    """On loopback too: the service answers 413 from the Content-Length alone, without waiting
    for (and reading) the body."""
    import http.client
    import socket
    from urllib.parse import urlsplit

    from tests.server.conftest import make_memory

    for s in serve_memory(make_memory(tmp_path / "m.mem"), max_upload_bytes=200_000):
        u = urlsplit(s.url)
        with socket.create_connection((u.hostname, u.port), timeout=10) as sock:
            sock.sendall(
                f"POST /ask HTTP/1.1\r\nHost: {u.netloc}\r\nContent-Type: application/json\r\n"
                "Content-Length: 50000000\r\n\r\n".encode()
            )
            reply = http.client.HTTPResponse(sock)
            reply.begin()  # a timeout here: the service waited for the body
            assert reply.status == 413
            assert "over the limit" in json.loads(reply.read())["error"]


def test_broken_json_is_named_as_such(served: Served):
    with served.client() as c:
        r = c.post("/ask", content=b'{"question": ', headers={"content-type": "application/json"})
    assert r.status_code == 422
    assert one_line_error(r).startswith("body: not valid JSON")


def test_occupancy_map_north_up(served: Served):
    from ravenmem.nav.grid import MapConfig, OccupancyGrid

    with served.client() as c:
        none = c.get("/map")
        assert none.status_code == 404 and "no occupancy map" in one_line_error(none)
        assert c.get("/map.png").status_code == 404 and c.get("/info").json()["has_map"] is False
        grid = OccupancyGrid(MapConfig(resolution=0.5), origin=(-1.0, -2.0), shape=(8, 12))
        grid.known[:] = True
        grid.logodds[:] = -1.0  # free floor
        row, col = grid.world_to_cell(3.2, 1.1)
        grid.logodds[row, col] = 2.0  # one wall cell, north-east of the middle
        grid.save(served.mem.path)
        assert c.get("/info").json()["has_map"] is True  # the page asks for /map only then
        meta = c.get("/map").json()
        assert (
            meta["extent"] == [-1.0, -2.0, 5.0, 2.0]
            and meta["resolution"] == 0.5
            and meta["shape"] == [8, 12]
        )
        assert meta["image"] == f"{served.url}/map.png"
        png_bytes = c.get(meta["image"])
        assert png_bytes.headers["content-type"] == "image/png"
    img = np.asarray(Image.open(io.BytesIO(png_bytes.content)).convert("RGB"))
    assert img.shape == (8, 12, 3)
    dark = np.argwhere(img.sum(axis=2) < 100)
    assert dark.tolist() == [[8 - 1 - row, col]]  # picture row 0 is the north edge


def test_a_map_file_leading_out_of_the_memory_is_not_read(served: Served, tmp_path):
    from ravenmem.nav.grid import MapConfig, OccupancyGrid

    outside = tmp_path / "elsewhere"
    OccupancyGrid(MapConfig(), shape=(4, 4)).save(outside)
    for name in ("map.json", "map.npz"):
        (served.mem.path / name).symlink_to(outside / name)
    with served.client() as c:
        assert c.get("/map").status_code == 404


def test_pictures_outside_the_memory_folder_are_never_served(tmp_path):
    """A memory built without thumbnails points at the original frames, elsewhere on the disk:
    the service serves none of them and names no path outside the folder."""
    import ravenmem
    from ravenmem.types import Frame, Pose
    from tests.conftest import ColorEmbedder, solid

    (tmp_path / "frames").mkdir()
    frames = []
    for i, colour in enumerate(["red", "green", "blue"]):
        p = tmp_path / "frames" / f"{i}.png"
        Image.fromarray(solid(colour)).save(p)
        frames.append(
            Frame(image=solid(colour), t=T0 + i, pose=Pose(i, 0, 0, 0), source="s", index=i, path=str(p))
        )
    mem = ravenmem.create(tmp_path / "m.mem", embedder=ColorEmbedder(), ocr=False, thumb_size=0)
    mem.add_frames(frames)
    assert mem.get([1])[0].image_path == str(tmp_path / "frames" / "0.png")  # it does point out
    for s in serve_memory(mem):
        with s.client() as c:
            r = c.get("/memories/1/image")
            assert r.status_code == 404 and "no picture" in one_line_error(r)
            texts = [c.get(p).text for p in ("/memories/1", "/search/text?q=red&k=3", "/info", "/trajectory")]
            assert c.get("/memories/1").json()["image"] is None  # no URL that would answer 404
            assert [h["image"] for h in c.get("/search/text?q=red&k=3").json()["results"]] == [None] * 3
    assert not any(str(tmp_path) in t for t in texts)
