"""Sources -> keyframes -> the real Memory through the ingest pipeline (tiny colour embedder)."""

from __future__ import annotations

from pathlib import Path

import pytest

import ravenmem
from ravenmem.ingest.keyframes import KeyframeConfig
from ravenmem.ingest.pipeline import ingest
from ravenmem.ingest.poses import SKIP_OUTSIDE
from ravenmem.ingest.sources import open_source

from .test_video import N, write_video


def test_video_into_memory_with_keyframes(tmp_path: Path, color_embedder: object) -> None:
    vid = tmp_path / "walk.mp4"
    write_video(vid)
    poses = tmp_path / "poses.csv"
    poses.write_text("t,x,y,yaw\n0.5,0,0,0\n2.0,3,0,0\n")
    mem = ravenmem.create(tmp_path / "mem", embedder=color_embedder, ocr=False)  # type: ignore[arg-type]
    try:
        src = open_source(vid, poses=poses)
        report = ingest(src, mem, keyframes=KeyframeConfig.from_spec("min_translation=0.5"), progress=False)
        # 16 posed frames 0.2 m apart (x = 2 (t - 0.5)): keep every third, from x = 0
        assert report.frames_seen == N and report.kept == 6
        assert report.skipped[SKIP_OUTSIDE] == 14
        assert report.raw_bytes == src.stats.raw_bytes > 0
        recs = mem.all_records()
        assert [round(r.pose.x, 6) for r in recs] == pytest.approx([0.0, 0.6, 1.2, 1.8, 2.4, 3.0])
        assert [r.frame_index for r in recs] == [5, 8, 11, 14, 17, 20]
        hits = mem.search_position(1.2, 0.0, k=1)
        assert hits[0].memory.frame_index == 11
    finally:
        mem.close()


def test_tum_into_memory_keeps_original_paths(tmp_path: Path, tum_path: Path, color_embedder: object) -> None:
    mem = ravenmem.create(tmp_path / "mem", embedder=color_embedder, ocr=False, thumb_size=0)  # type: ignore[arg-type]
    try:
        report = ingest(
            open_source(tum_path), mem, keyframes=KeyframeConfig.from_spec("fps=1"), progress=False
        )
        assert report.frames_seen == 723 and report.skipped["pose gap too large"] == 3
        assert 25 <= report.kept <= 29  # ~27.7 s of recording at 1 frame per second
        rec = mem.all_records()[0]
        assert rec.image_path is not None and Path(rec.image_path).is_file()
    finally:
        mem.close()


def test_ingest_reads_text_in_a_thread_and_returns_once_it_is_stored(
    tmp_path: Path, color_embedder: object, monkeypatch: pytest.MonkeyPatch
) -> None:
    import threading

    from ravenmem.memory.folder import TEXT_JOURNAL_NAME

    readers: list[str] = []

    def reader() -> object:  # the background thread's OCR: names the thread that reads
        def read(image: object) -> str:
            readers.append(threading.current_thread().name)
            return "EXIT 7"

        return read

    monkeypatch.setattr("ravenmem.memory.facade.ocr_reader", reader)
    vid = tmp_path / "walk.mp4"
    write_video(vid)
    poses = tmp_path / "poses.csv"
    poses.write_text("t,x,y,yaw\n0.5,0,0,0\n2.0,3,0,0\n")
    path = tmp_path / "mem"
    with ravenmem.create(path, embedder=color_embedder, ocr=True, thumb_size=0) as mem:  # type: ignore[arg-type]
        report = ingest(
            open_source(vid, poses=poses),
            mem,
            keyframes=KeyframeConfig.from_spec("min_translation=0.5"),
            progress=False,
            batch_size=2,
        )
        assert report.kept == 6
        # every keyframe's text was read in the background thread, and stored before ingest returned
        assert readers == ["ravenmem-ocr"] * 6
        assert [r.ocr_text for r in mem.all_records()] == ["EXIT 7"] * 6
        assert not [p for p in path.iterdir() if TEXT_JOURNAL_NAME.fullmatch(p.name)]
        assert mem.search_text("exit", k=1)[0].ocr_match
