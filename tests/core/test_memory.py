"""The Memory facade over the embedded store, with a tiny exact embedder."""

from __future__ import annotations

import json
import threading

import numpy as np
import pytest

import ravenmem
from ravenmem.errors import EmbedderMismatchError, EmptyMemoryError, InputError
from ravenmem.types import Frame, Pose
from tests.conftest import ColorEmbedder, solid

T0 = 1_700_000_000.0
SEQ = ["red", "green", "blue", "yellow", "red", "cyan", "magenta", "blue", "white", "green"]


@pytest.fixture
def mem(tmp_path, color_embedder):
    m = ravenmem.create(tmp_path / "m.mem", embedder=color_embedder, ocr=False, thumb_size=32)
    frames = [
        Frame(image=solid(c), t=T0 + 10 * i, pose=Pose(float(i), 0.0, 0.0, 0.1 * i), source="test", index=i)
        for i, c in enumerate(SEQ)
    ]
    m.add_frames(frames)
    yield m
    m.close()


def test_text_search_ranks_by_cosine_and_returns_scores(mem):
    hits = mem.search_text("the red one", k=3)
    assert [h.memory.frame_index for h in hits[:2]] == sorted([0, 4]) or {
        h.memory.frame_index for h in hits[:2]
    } == {0, 4}
    assert hits[0].score == pytest.approx(1.0, abs=1e-5)
    assert hits[0].score >= hits[1].score >= hits[2].score


def test_filters_time_window_and_region(mem):
    hits = mem.search_text("red", k=3, after=T0 + 15)
    assert hits[0].memory.frame_index == 4 and all(h.memory.t >= T0 + 15 for h in hits)
    hits = mem.search_text("blue", k=5, near=(7.0, 0.0, 1.5))
    assert {h.memory.frame_index for h in hits} <= {6, 7, 8} and hits[0].memory.frame_index == 7
    # time expressions: seconds from start, and relative to the latest memory
    assert mem.search_text("red", k=1, before="+15")[0].memory.frame_index == 0
    assert mem.search_text("red", k=1, after="60 seconds ago")[0].memory.t >= T0 + 30


def test_time_tool_is_forward_chronological_from_t(mem):
    hits = mem.search_time("+25", k=4)
    assert [h.memory.frame_index for h in hits] == [3, 4, 5, 6]
    assert mem.search_time(T0 + 85, k=5)[0].memory.frame_index == 9
    assert mem.search_time(T0 + 85, k=5).__len__() == 1


def test_position_tool_nearest_with_radius(mem):
    hits = mem.search_position(3.2, 0.0, k=3)
    assert [h.memory.frame_index for h in hits] == [3, 4, 2]
    assert hits[0].distance == pytest.approx(0.2, abs=1e-6)
    assert len(mem.search_position(3.2, 0.0, k=10, radius=1.0)) == 2
    with pytest.raises(InputError):
        mem.search_position(0, 0, radius=-1)


def test_image_tool(mem, tmp_path):
    from PIL import Image

    Image.fromarray(solid("magenta")).save(tmp_path / "q.png")
    assert mem.search_image(str(tmp_path / "q.png"), k=1)[0].memory.frame_index == 6
    assert mem.search_image(solid("cyan"), k=1)[0].memory.frame_index == 5


def test_fluent_query(mem):
    hits = mem.query().after("+30").near(8.0, 0.0, 2.5).text("green").limit(2).run()
    assert hits[0].memory.frame_index == 9
    assert len(hits) == 2
    with pytest.raises(InputError):
        mem.query().text("a").time(3)


def test_thumbnails_and_records(mem):
    rec = mem.all_records()[1]
    assert mem.get([rec.id])[0].frame_index == 1
    img = mem.load_image(rec)
    assert img is not None and img.shape[2] == 3 and max(img.shape[:2]) <= 32
    assert np.abs(img[5, 5].astype(int) - [0, 255, 0]).max() <= 8
    assert [r.frame_index for r in mem.all_records()] == list(range(10))


def test_reopen_checks_embedder(tmp_path, mem, color_embedder):
    path = mem.path
    mem.close()
    with ravenmem.open(path, embedder=color_embedder) as m2:
        assert m2.count() == 10
    with pytest.raises(EmbedderMismatchError):
        ravenmem.open(path, embedder="offline")

    class Other(ColorEmbedder):
        name = "other"

    with pytest.raises(EmbedderMismatchError):
        ravenmem.open(path, embedder=Other())


def test_bad_inputs(tmp_path, color_embedder, mem):
    with pytest.raises(InputError, match="does not exist"):
        ravenmem.open(tmp_path / "nope")
    with pytest.raises(InputError, match="already holds"):
        ravenmem.create(mem.path, embedder=color_embedder)
    (tmp_path / "bad").mkdir()
    (tmp_path / "bad" / "memory.json").write_text("{not json")
    with pytest.raises(InputError, match="not valid JSON"):
        ravenmem.open(tmp_path / "bad")
    with pytest.raises(InputError, match="RGB uint8"):
        mem.add(np.zeros((4, 4), np.uint8), Pose(0, 0), T0)
    with pytest.raises(InputError):
        mem.search_text("   ")
    assert mem.count() == 10  # nothing lost by the failed calls


def test_empty_memory_is_clear(tmp_path, color_embedder):
    with ravenmem.create(tmp_path / "e.mem", embedder=color_embedder, ocr=False) as m:
        with pytest.raises(EmptyMemoryError):
            m.search_text("red")
        with pytest.raises(EmptyMemoryError):
            m.search_time("+3")
        assert m.info()["memories"] == 0


def test_live_add_while_searching(tmp_path, color_embedder):
    m = ravenmem.create(tmp_path / "live.mem", embedder=color_embedder, ocr=False, thumb_size=0)
    m.add(solid("red"), Pose(0, 0), T0)
    errors: list[BaseException] = []
    stop = threading.Event()

    def searcher():
        try:
            while not stop.is_set():
                assert m.search_text("red", k=1)[0].score > 0.99
                m.search_position(0, 0, k=3)
        except BaseException as e:  # noqa: BLE001 - surfaced below
            errors.append(e)

    th = [threading.Thread(target=searcher) for _ in range(2)]
    for t in th:
        t.start()
    for i in range(1, 60):
        m.add(solid(SEQ[i % len(SEQ)]), Pose(float(i), 0), T0 + i)
    stop.set()
    for t in th:
        t.join()
    assert not errors, errors[0]
    assert m.count() == 60
    m.close()


def test_manifest_and_info(mem):
    manifest = json.loads((mem.path / "memory.json").read_text())
    assert manifest["embedder"] == "test-color" and manifest["dim"] == 4
    info = mem.info()
    assert info["memories"] == 10 and info["duration_s"] == pytest.approx(90)
    assert info["bytes_per_memory"] > 0
