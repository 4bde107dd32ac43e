"""Live adds under load: one writer, searches meanwhile, and no acknowledged memory lost."""

from __future__ import annotations

import io
import signal
import threading
import time

import httpx
import numpy as np
import pytest
from PIL import Image

import ravenmem
from ravenmem.ingest.keyframes import KeyframeConfig
from ravenmem.runtime.live import BusyError, LiveWriter
from ravenmem.types import Pose
from tests.agent.conftest import SCENE, T0
from tests.conftest import ColorEmbedder, solid
from tests.server.conftest import Served, make_memory, serve_refused, serve_subprocess, stop

COLOURS = [(255, 0, 0), (0, 255, 0), (0, 0, 255), (255, 255, 0), (0, 255, 255), (255, 0, 255)]


def png(i: int) -> bytes:
    buf = io.BytesIO()
    Image.new("RGB", (24, 16), COLOURS[i % len(COLOURS)]).save(buf, "PNG")
    return buf.getvalue()


def add(c: httpx.Client, i: int, source: str) -> httpx.Response:
    return c.post(
        "/memories",
        files={"image": ("f.png", png(i), "image/png")},
        data={"x": str(100 + i), "y": str(len(source)), "t": str(T0 + 1000 + i), "source": source},
    )


def test_concurrent_adds_and_searches(served: Served):
    errors: list[str] = []
    acked: dict[int, tuple[float, float]] = {}
    searches = [0]
    stop = threading.Event()
    lock = threading.Lock()

    def adder(source: str) -> None:
        with served.client() as c:
            for i in range(15):
                r = add(c, i, source)
                if r.status_code != 201:
                    errors.append(f"add {r.status_code} {r.text}")
                    continue
                m = r.json()["memory"]
                with lock:
                    acked[m["id"]] = (m["x"], m["y"])

    def searcher(n: int) -> None:
        with served.client() as c:
            while not stop.is_set():
                for path, params in (
                    ("/search/text", {"q": "red", "k": 5}),
                    ("/search/time", {"t": "+0s", "k": 5}),
                    ("/search/position", {"x": 105, "y": 3, "k": 3}),
                ):
                    r = c.get(path, params=params)
                    if r.status_code != 200:
                        errors.append(f"search {r.status_code} {r.text}")
                    with lock:
                        searches[0] += 1

    adders = [threading.Thread(target=adder, args=(s,)) for s in ("cam_a", "cam_bb", "cam_ccc")]
    readers = [threading.Thread(target=searcher, args=(n,)) for n in range(3)]
    for th in readers + adders:
        th.start()
    for th in adders:
        th.join(120)
    stop.set()
    for th in readers:
        th.join(60)
    assert errors == []
    assert len(acked) == 45 and searches[0] > 10
    assert served.mem.count() == len(SCENE) + 45
    recs = {r.id: r for r in served.mem.get(sorted(acked))}
    assert {i: (r.pose.x, r.pose.y) for i, r in recs.items()} == acked
    # each source kept its own order (its frame_index counts its frames)
    for source in ("cam_a", "cam_bb", "cam_ccc"):
        mine = sorted((r.t, r.frame_index) for r in recs.values() if r.source == source)
        assert [fi for _, fi in mine] == list(range(15))


def test_writer_bounds_its_queue_and_stops_cleanly(tmp_path):
    mem = make_memory(tmp_path / "m.mem")

    class Slow(ColorEmbedder):
        def embed_images(self, images):
            time.sleep(0.2)
            return super().embed_images(images)

    mem._embedder = Slow()
    w = LiveWriter(mem, KeyframeConfig.only(), max_pending=2, batch=1).start()
    futures = []
    with pytest.raises(BusyError, match="waiting"):
        for i in range(10):
            futures.append(w.submit(solid("red"), Pose(0, 0), T0 + 2000 + i))
    assert 2 <= len(futures) <= 3  # two queued (plus, perhaps, one the writer took already)
    w.close()
    assert all(f.result(10).stored for f in futures)  # queued frames are stored before it stops
    with pytest.raises(ravenmem.errors.InputError, match="closing"):
        w.submit(solid("red"), Pose(0, 0), T0 + 3000)
    with pytest.raises(ravenmem.errors.InputError, match="RGB"):
        LiveWriter(mem).start().submit(np.zeros((4, 4), np.uint8), Pose(0, 0), T0)
    mem.close()


def test_sigkill_right_after_acknowledged_adds_loses_none(tmp_path):
    path = tmp_path / "m.mem"
    make_memory(path).close()
    proc, url = serve_subprocess(path)
    acked: dict[int, float] = {}
    try:
        with httpx.Client(base_url=url, timeout=30) as c:
            for i in range(25):
                r = add(c, i, "robot")
                assert r.status_code == 201, r.text
                acked[r.json()["id"]] = r.json()["memory"]["x"]
        proc.send_signal(signal.SIGKILL)  # no chance to flush, close or save anything
        proc.wait(30)
    finally:
        if proc.poll() is None:
            proc.kill()
    mem = ravenmem.open(path)
    try:
        assert mem.count() == len(SCENE) + 25
        assert {r.id: r.pose.x for r in mem.get(sorted(acked))} == acked
    finally:
        mem.close()


def test_sigkill_during_a_stream_of_adds_keeps_every_acknowledged_one(tmp_path):
    path = tmp_path / "m.mem"
    make_memory(path).close()
    proc, url = serve_subprocess(path)
    acked: list[int] = []
    failed = threading.Event()

    def stream() -> None:
        with httpx.Client(base_url=url, timeout=30) as c:
            for i in range(10_000):
                try:
                    r = add(c, i, "robot")
                except httpx.HTTPError:
                    failed.set()
                    return
                acked.append(r.json()["id"])

    th = threading.Thread(target=stream, daemon=True)
    th.start()
    while len(acked) < 30:
        time.sleep(0.01)
    proc.send_signal(signal.SIGKILL)
    proc.wait(30)
    th.join(30)
    assert failed.is_set()
    mem = ravenmem.open(path)
    try:
        n = mem.count()
        assert n >= len(SCENE) + len(acked)  # a frame stored but not yet answered may be there too
        assert len(mem.get(acked)) == len(acked)
    finally:
        mem.close()


def test_sigterm_stores_the_queue_and_notes_the_live_counts(tmp_path):
    path = tmp_path / "m.mem"
    make_memory(path).close()
    proc, url = serve_subprocess(path)
    with httpx.Client(base_url=url, timeout=30) as c:
        for i in range(4):
            assert add(c, i, "robot").status_code == 201
        assert add(c, 0, "robot").json()["skipped"] == "non-monotonic timestamp"
    proc.send_signal(signal.SIGTERM)
    assert proc.wait(60) in (0, -signal.SIGTERM)  # uvicorn re-raises the signal after a clean stop
    mem = ravenmem.open(path)
    try:
        assert mem.count() == len(SCENE) + 4
        live = [r for r in mem.manifest.ingests if r.get("source") == "live"]
        assert live and live[-1]["frames_seen"] == 5 and live[-1]["kept"] == 4
        assert live[-1]["skipped"] == {"non-monotonic timestamp": 1}
    finally:
        mem.close()


def test_a_robot_can_start_from_an_empty_memory(tmp_path):
    path = tmp_path / "new.mem"
    proc, url = serve_subprocess(path, "--create", "--embedder", "test-color", "--no-ocr")
    try:
        with httpx.Client(base_url=url, timeout=30) as c:
            assert c.get("/health").json()["memories"] == 0
            empty = c.get("/search/text", params={"q": "red"})
            assert empty.status_code == 400 and "is empty" in empty.json()["error"]
            assert str(tmp_path) not in empty.text  # the folder's name only, not where it lies
            assert c.get("/trajectory").json()["points"] == []
            for i in range(3):
                assert add(c, i, "robot").status_code == 201
            hits = c.get("/search/text", params={"q": "red", "k": 1}).json()["results"]
            assert hits[0]["id"] == 1 and hits[0]["offset_s"] == 0.0
    finally:
        proc.send_signal(signal.SIGINT)
        proc.wait(60)
    with ravenmem.open(path) as mem:
        assert mem.count() == 3 and mem.manifest.embedder == "test-color" and not mem.ocr_enabled


def test_the_service_is_the_one_writer_of_its_memory(tmp_path):

    path = tmp_path / "m.mem"
    make_memory(path).close()
    proc, url = serve_subprocess(path)
    try:
        second = serve_refused(path)
        assert second.returncode == 2 and "Traceback" not in second.stderr
        assert f"pid {proc.pid}" in second.stderr and "one writer at a time" in second.stderr
        with pytest.raises(ravenmem.errors.MemoryBusyError):  # nor can this process write to it
            ravenmem.open(path, writable=True)
        reader, reader_url = serve_subprocess(path, "--read-only")  # readers may run beside it
        try:
            with httpx.Client(timeout=30) as c:
                with httpx.Client(base_url=url, timeout=30) as writer:
                    assert add(writer, 0, "robot").status_code == 201
                # a reader serves the memory as it was when it opened (the store reads once)
                assert c.get(reader_url + "/health").json()["memories"] == len(SCENE)
                refused = c.post(
                    reader_url + "/memories",
                    files={"image": ("f.png", png(1), "image/png")},
                    data={"x": "1", "y": "1"},
                )
                assert refused.status_code == 400 and "read-only" in refused.json()["error"]
        finally:
            reader.send_signal(signal.SIGINT)
            reader.wait(60)
    finally:
        proc.send_signal(signal.SIGINT)
        proc.wait(60)
    with ravenmem.open(path, writable=True) as mem:  # released when the service stopped
        assert mem.is_writer and mem.count() == len(SCENE) + 1


def test_live_adds_with_depth_update_the_memory_map(tmp_path):
    """`ravenmem serve --intrinsics ... --camera-frame optical`: frames posted with a depth PNG
    are fused into the memory's map (every one, keyframe or not), saved when the service stops;
    a bad depth upload is a one-line 400 and stores nothing."""
    from scipy.spatial.transform import Rotation

    from ravenmem.nav import load_map
    from tests.nav.depthscene import look, render

    path = tmp_path / "live.mem"
    extra = ["--create", "--embedder", "test-color", "--no-ocr", "--keyframes", "stride=4"]
    proc, url = serve_subprocess(path, *extra, "--intrinsics", "200,200,160,120", "--camera-frame", "optical")
    try:
        with httpx.Client(base_url=url, timeout=30) as c:
            for i in range(12):  # a camera walking towards a wall at x = 4.0 .. 4.2 m, depth in mm
                cam = look(0.1 * i, 0.05 * i, 1.0, 0.1 * np.sin(i), np.radians(15))
                d = io.BytesIO()
                Image.fromarray(
                    np.round(render(cam, [(4.0, -3.0, 4.2, 3.0, 2.0)]) * 1000).astype(np.uint16)
                ).save(d, "PNG")
                q = Rotation.from_matrix(cam[:3, :3]).as_quat()
                x, y, z = cam[:3, 3]
                pose = dict(zip(("x", "y", "z", "qx", "qy", "qz", "qw"), map(str, (x, y, z, *q))))
                r = c.post(
                    "/memories",
                    files={
                        "image": ("f.png", png(i), "image/png"),
                        "depth": ("d.png", d.getvalue(), "image/png"),
                    },
                    data={**pose, "t": str(T0 + i), "source": "head"},
                )
                assert r.status_code in (200, 201), r.text
            bad = c.post(
                "/memories",
                files={"image": ("f.png", png(0), "image/png"), "depth": ("d.png", png(1), "image/png")},
                data={"x": "0", "y": "0", "t": str(T0 + 20)},
            )
            assert bad.status_code == 400 and "one channel of depth" in bad.json()["error"]
    finally:
        proc.send_signal(signal.SIGINT)
        proc.wait(60)
    grid = load_map(path)
    assert grid.kind == "recorded" and grid.meta["sources"]["head"] == T0 + 11  # all 12 frames mapped
    _, cc = np.nonzero(grid.occupied)
    wall_x = grid.origin[0] + (cc + 0.5) * grid.resolution
    assert len(wall_x) > 20 and np.all((wall_x > 3.85) & (wall_x < 4.35))
    with ravenmem.open(path) as mem:
        assert mem.count() == 3  # stride 4: three keyframes; the map took every frame
        assert mem.manifest.ingests[-1]["map"]["frames_mapped"] == 12


def test_serve_without_keyframe_options_stores_the_same_frame_once(tmp_path):
    """`ravenmem serve` with no --keyframes uses the default rules, as ingest does: the same
    frame posted twice is one memory (the same pose: too little motion; the same picture from
    a pose 2 m on: similar to the last keyframe), and `--keyframes all` keeps both."""
    path = tmp_path / "m.mem"
    make_memory(path).close()
    outcomes: dict[str, list[object]] = {}
    for name, extra in (("default", ()), ("all", ("--keyframes", "all"))):
        proc, url = serve_subprocess(path, *extra)
        try:
            with httpx.Client(base_url=url, timeout=30) as c:
                base = 5000 if name == "default" else 6000
                got = []
                for dt, x in ((0, 50.0), (1, 50.0), (2, 52.0)):
                    r = c.post(
                        "/memories",
                        files={"image": ("f.png", png(0), "image/png")},
                        data={"x": str(x), "y": "7", "t": str(T0 + base + dt), "source": "cam"},
                    )
                    assert r.status_code in (200, 201), r.text
                    got.append(r.json()["skipped"] or "stored")
                outcomes[name] = got
        finally:
            stop(proc)
    assert outcomes["default"] == ["stored", "too little motion", "similar to last keyframe"]
    assert outcomes["all"] == ["stored", "stored", "stored"]
    with ravenmem.open(path) as mem:
        assert mem.count() == len(SCENE) + 1 + 3
