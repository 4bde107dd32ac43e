"""Text read after the write: live frames are answered before their OCR, searchable by picture at
once and by their words when the text lands, and a crash in between loses neither."""

from __future__ import annotations

import io
import signal
import threading
import time
from pathlib import Path

import httpx
import numpy as np
import pytest
from PIL import Image, ImageDraw, ImageFont

import ravenmem
from ravenmem.ingest.keyframes import KeyframeConfig
from ravenmem.memory.folder import TEXT_JOURNAL_NAME
from ravenmem.runtime.live import LiveWriter
from ravenmem.types import Frame, Pose
from tests.conftest import ColorEmbedder, solid
from tests.server.conftest import REPO, serve_subprocess

T0 = 1_700_000_000.0
BACKGROUNDS = [(150, 20, 20), (20, 120, 20), (20, 20, 150)]


def sign(word: str, background: tuple[int, int, int]) -> np.ndarray:
    """A 640x480 frame with one big word on it (white on `background`)."""
    import matplotlib

    font = Path(matplotlib.get_data_path()) / "fonts" / "ttf" / "DejaVuSans-Bold.ttf"
    if not font.is_file():
        pytest.skip(f"no TTF font at {font}")
    im = Image.new("RGB", (640, 480), background)
    ImageDraw.Draw(im).text((80, 160), word, font=ImageFont.truetype(str(font), 110), fill=(255, 255, 255))
    return np.asarray(im)


def jpeg(a: np.ndarray) -> bytes:
    buf = io.BytesIO()
    Image.fromarray(a).save(buf, "JPEG", quality=95)
    return buf.getvalue()


def journals(path: Path) -> list[str]:
    return [p.name for p in path.iterdir() if TEXT_JOURNAL_NAME.fullmatch(p.name)]


def test_text_is_read_after_the_write_and_lands_for_the_text_search(tmp_path, monkeypatch):
    release = threading.Event()

    def slow_reader():  # what the memory's background thread reads with
        def read(image: np.ndarray) -> str:
            assert release.wait(60)
            return "EXIT 42"

        return read

    monkeypatch.setattr("ravenmem.memory.facade.ocr_reader", slow_reader)
    path = tmp_path / "m.mem"
    mem = ravenmem.create(path, embedder=ColorEmbedder(), ocr=True, thumb_size=32)
    try:
        ids = mem.add_frames([Frame(solid("red"), T0, Pose(1, 2), "cam", 0)], text="later")
        # stored and searchable by picture at once; its words are not read yet (journalled)
        assert mem.get(ids)[0].ocr_text == "" and len(journals(path)) == 1
        hits = mem.search_text("exit", k=1)
        assert hits[0].memory.id == ids[0] and not hits[0].ocr_match
        assert not mem.wait_text(0.1)
        release.set()
        assert mem.wait_text(60)
        assert mem.get(ids)[0].ocr_text == "EXIT 42" and journals(path) == []
        hits = mem.search_text("exit", k=1)
        assert hits[0].memory.id == ids[0] and hits[0].ocr_match
        # text="now" (the default) reads it before the write
        mem._ocr = lambda image: "GO"
        now = mem.add_frames([Frame(solid("green"), T0 + 1, Pose(3, 2), "cam", 1)], text="now")
        assert mem.get(now)[0].ocr_text == "GO" and journals(path) == []
        with pytest.raises(ravenmem.errors.InputError, match="text must be 'now' or 'later'"):
            mem.add_frames([Frame(solid("blue"), T0 + 2, Pose(5, 2), "cam", 2)], text="soon")
    finally:
        mem.close()


def test_a_skipped_live_frame_is_answered_without_waiting_for_the_embedder(tmp_path):
    mem = ravenmem.create(tmp_path / "m.mem", embedder=ColorEmbedder(), ocr=False, thumb_size=0)
    gate = threading.Event()

    class Held(ColorEmbedder):
        def embed_images(self, images):
            assert gate.wait(60)
            return super().embed_images(images)

    mem._embedder = Held()
    w = LiveWriter(mem, KeyframeConfig()).start()
    try:
        first = w.submit(solid("red"), Pose(0, 0), T0)
        same = w.submit(solid("red"), Pose(0, 0), T0 + 1)  # did not move: the prefilter skips it
        late = w.submit(solid("red"), Pose(0, 0), T0 - 5)  # goes back in time
        assert same.done() and same.result().skipped == "too little motion"
        assert late.done() and late.result().skipped == "non-monotonic timestamp"
        assert not first.done()  # still waiting for the embedder
        gate.set()
        assert first.result(30).stored
        assert w.stats.as_dict() == {
            "frames_seen": 3,
            "kept": 1,
            "skipped": {"too little motion": 1, "non-monotonic timestamp": 1},
        }
    finally:
        w.close()
        mem.close()


def test_kill_9_before_the_text_lands_loses_neither_memory_nor_text(tmp_path):
    """The service acknowledges three frames with words on them, then is killed while their
    text is still being read (an OCR slowed to a minute a picture); the next writer reads it."""
    path = tmp_path / "m.mem"
    ravenmem.create(path, embedder=ColorEmbedder(), ocr=True, thumb_size=64).close()
    words = ["EXIT", "STOP", "LAB"]
    proc, url = serve_subprocess(path, entry=REPO / "tests" / "server" / "serve_slow_ocr.py")
    acked: dict[int, str] = {}
    try:
        with httpx.Client(base_url=url, timeout=60) as c:
            for i, word in enumerate(words):
                r = c.post(
                    "/memories",
                    files={"image": ("f.jpg", jpeg(sign(word, BACKGROUNDS[i])), "image/jpeg")},
                    data={"x": str(3.0 * i), "y": "0", "t": str(T0 + i), "source": "robot"},
                )
                assert r.status_code == 201, r.text
                acked[r.json()["id"]] = word
                assert r.json()["memory"]["ocr_text"] == ""  # answered before its text is read
        deadline = time.monotonic() + 30
        while len(journals(path)) < len(words) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert len(journals(path)) == len(words)
        proc.send_signal(signal.SIGKILL)
        proc.wait(30)
    finally:
        if proc.poll() is None:
            proc.kill()
    with ravenmem.open(path, embedder=ColorEmbedder()) as mem:
        assert {r.id for r in mem.get(sorted(acked))} == set(acked)  # every acknowledged memory
        assert all(r.ocr_text == "" for r in mem.get(sorted(acked)))  # a reader changes nothing
        mem.acquire_writer()  # the next writer reads the journalled text (real OCR)
        got = {r.id: r.ocr_text for r in mem.get(sorted(acked))}
        assert journals(path) == []
        for i, word in acked.items():
            assert word in got[i].upper(), got
            top = mem.search_text(word.lower(), k=1)[0]
            assert top.memory.id == i and top.ocr_match


def test_a_live_stream_and_the_same_recording_keep_the_same_frames_for_the_same_reasons(tmp_path):
    """One admission stage (ingest.admit): a robot streaming frames to a served memory and an
    ingest of the same frames keep the same keyframes and name the same skip reasons."""
    from ravenmem.ingest.pipeline import PREFILTER, ingest

    stream = [  # (colour, x, t): what each rule sees
        ("red", 0.0, 0.0),  # kept
        ("red", 0.1, 1.0),  # too little motion
        ("red", 1.0, 2.0),  # moved, but looks like the last keyframe
        ("green", 2.0, 3.0),  # kept
        ("green", 3.0, 2.5),  # back in time
        ("blue", 3.0, 4.0),  # kept
        ("blue", 3.0, 10.0),  # 5 s passed, but looks like the last keyframe
        ("red", 3.1, 10.5),  # too little motion since the frame before
        ("red", 4.0, 11.0),  # kept
    ]
    frames = [Frame(solid(c), T0 + t, Pose(x, 0), "cam", i) for i, (c, x, t) in enumerate(stream)]

    class Recording:
        name = "recording"

        def __iter__(self):
            return iter(frames)

    with ravenmem.create(tmp_path / "ingest.mem", embedder=ColorEmbedder(), ocr=False, thumb_size=0) as mem:
        report = ingest(Recording(), mem, KeyframeConfig(), progress=False, batch_size=2)
        recorded = [r.frame_index for r in mem.all_records()]
    with ravenmem.create(tmp_path / "live.mem", embedder=ColorEmbedder(), ocr=False, thumb_size=0) as mem:
        w = LiveWriter(mem, KeyframeConfig()).start()
        try:
            answers = [w.add(f.image, f.pose, f.t, source="cam") for f in frames]
        finally:
            w.close()
        live = [r.frame_index for r in mem.all_records()]
    assert recorded == live == [0, 3, 5, 8]
    assert [a.stored for a in answers] == [i in live for i in range(len(frames))]
    # the same reasons; the ingest report sums the cheap rules' (docs/ingest.md)
    assert w.stats.skipped == {
        "too little motion": 2,
        "similar to last keyframe": 2,
        "non-monotonic timestamp": 1,
    }
    assert report.skipped == {
        PREFILTER: 2,
        "similar to last keyframe": 2,
        "non-monotonic timestamp": 1,
    }


def test_an_unreadable_text_journal_is_set_aside_and_the_memory_still_opens(tmp_path):
    path = tmp_path / "m.mem"
    ravenmem.create(path, embedder=ColorEmbedder(), ocr=True, thumb_size=0).close()
    bad = path / "pending-text-0123456789ab.npz"
    bad.write_bytes(b"not a journal")
    with ravenmem.open(path, embedder=ColorEmbedder()) as mem:
        mem.acquire_writer()  # recovery runs: the journal cannot be read, the writer still starts
        assert journals(path) == [] and (path / "pending-text-0123456789ab.npz.aside").is_file()
        mem._ocr = lambda image: ""
        assert mem.add_frames([Frame(solid("red"), T0, Pose(1, 2), "cam", 0)], text="now")
