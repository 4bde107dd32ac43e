"""Source identity (what "the same recording" means for resuming) and frame counts."""

from __future__ import annotations

import json
import os
import shutil
from functools import partial
from pathlib import Path

import numpy as np
from PIL import Image

import ravenmem
from ravenmem.ingest.folder import FolderSource
from ravenmem.ingest.tum import TumSource
from ravenmem.ingest.video import VideoSource
from ravenmem.ros.bag import RosbagSource
from ravenmem.types import Frame, Pose
from tests.cli.helpers import run_cli

from .bags import write_bag
from .test_video import N, write_video

REPO = Path(__file__).resolve().parents[2]
EMBEDDER = "offline:tiles=1:res=128"


rm = partial(run_cli, timeout=600)


def image_folder(path: Path, seed: int, n: int = 6) -> Path:
    """n timestamped images (distinct random content per seed) and a pose track."""
    path.mkdir(parents=True)
    rng = np.random.default_rng(seed)
    for i in range(n):
        img = rng.integers(0, 256, (48, 64, 3), dtype=np.uint8)
        Image.fromarray(img).save(path / f"{1000 + i}.png")
    (path / "poses.csv").write_text(f"t,x,y,yaw\n999,0,0,0\n{1000 + n},{n},0,0\n")
    return path


def test_identity_ignores_location_and_tells_recordings_apart(tmp_path: Path) -> None:
    a = image_folder(tmp_path / "one" / "run", seed=1)
    b = image_folder(tmp_path / "two" / "run", seed=2)  # same folder name, other images
    ida = FolderSource(a).identity()
    assert ida.startswith("folder:run@") and ida != FolderSource(b).identity()
    moved = tmp_path / "elsewhere" / "run"
    shutil.move(str(a.parent), str(tmp_path / "elsewhere"))
    assert FolderSource(moved).identity() == ida
    os.chdir(moved.parent)
    try:
        assert FolderSource(Path("run")).identity() == ida  # a relative path: same recording
    finally:
        os.chdir(REPO)


def test_every_source_knows_its_frame_count_and_identity(tmp_path: Path, tum_path: Path) -> None:
    tum = TumSource(tum_path)
    assert tum.frame_count == 723 and tum.identity().startswith("tum:tum_fr1_rpy@")
    assert FolderSource(image_folder(tmp_path / "imgs", seed=3)).frame_count == 6
    vid = tmp_path / "walk.mp4"
    write_video(vid)
    (tmp_path / "poses.csv").write_text("t,x,y\n0,0,0\n3,1,0\n")
    v = VideoSource(vid, poses=tmp_path / "poses.csv")
    assert v.frame_count == N and v.identity().startswith("video:walk.mp4@")
    bag = write_bag(tmp_path / "rec.bag", "ros1")
    raw = RosbagSource(bag, image_topic="/camera/image_raw", pose_topic="/odom")
    comp = RosbagSource(bag, image_topic="/camera/compressed", pose_topic="/odom")
    assert raw.frame_count == 9 and comp.frame_count == 3
    assert raw.identity() != comp.identity()  # two cameras of one bag are two recordings
    assert raw.identity() == RosbagSource(bag, image_topic="/camera/image_raw", pose_topic="/tf").identity()


def test_moved_folder_and_relative_path_resume_namesake_does_not(tmp_path: Path) -> None:
    mem = tmp_path / "m.mem"
    a = image_folder(tmp_path / "day1" / "run", seed=1)
    # every frame: random-noise images are alike to an embedder, and this is about resuming
    common = ["--memory", str(mem), "--no-ocr", "--embedder", EMBEDDER, "--keyframes", "all", "--json"]
    first = rm("ingest", str(a), *common)
    assert first.returncode == 0, first.stderr
    assert json.loads(first.stdout)["kept"] == 6

    moved = tmp_path / "archive" / "run"
    shutil.move(str(a.parent), str(tmp_path / "archive"))
    again = rm("ingest", "run", *common, cwd=moved.parent)  # moved, and given as a relative path
    assert again.returncode == 0, again.stderr
    rep = json.loads(again.stdout)
    assert rep["kept"] == 0 and rep["skipped"]["already in memory"] == 6 and rep["memories_total"] == 6

    other = image_folder(tmp_path / "day2" / "run", seed=2)  # same name, other recording, same times
    third = rm("ingest", str(other), *common)
    assert third.returncode == 0, third.stderr
    rep = json.loads(third.stdout)
    assert rep["kept"] == 6 and "already in memory" not in rep["skipped"] and rep["memories_total"] == 12
    assert rep["source_id"] != json.loads(first.stdout)["source_id"]


def test_memories_written_before_identities_are_recognised(tmp_path: Path, color_embedder: object) -> None:
    """Older versions stored the path string as the source: re-ingesting resumes from those."""
    folder = image_folder(tmp_path / "run", seed=4)
    mem_path = tmp_path / "m.mem"
    mem = ravenmem.create(mem_path, embedder=color_embedder, ocr=False, thumb_size=0)  # type: ignore[arg-type]
    src = FolderSource(folder)
    old = [Frame(f.image, f.t, f.pose, source=str(folder), index=f.index) for f in list(src)[:4]]
    mem.add_frames(old)
    mem.close()

    from ravenmem.ingest.pipeline import ingest

    mem = ravenmem.open(mem_path, embedder=color_embedder)  # type: ignore[arg-type]
    try:
        from ravenmem.ingest.keyframes import KeyframeConfig

        rep = ingest(FolderSource(folder), mem, keyframes=KeyframeConfig.only(), progress=False)
        assert rep.skipped["already in memory"] == 4 and rep.kept == 2 and mem.count() == 6
        recs = mem.all_records()
        assert [r.frame_index for r in recs] == [0, 1, 2, 3, 4, 5]
        assert {r.source for r in recs[4:]} == {src.identity()}
        # the path now holds another recording: index and time must both match, so nothing is lost
        other = Frame(old[0].image, old[0].t + 0.5, Pose(0, 0), source=str(folder), index=0)
        from ravenmem.ingest.pipeline import StoredFrames

        assert StoredFrames(mem.store, "folder:run@000000000000").find(other) is None
        assert StoredFrames(mem.store, "folder:run@000000000000").find(old[1]) == recs[1].id
    finally:
        mem.close()
