"""Image folder source: times from file names, per-image pose rows, or a fixed fps."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from ravenmem.errors import InputError
from ravenmem.ingest.common import SKIP_BAD_IMAGE
from ravenmem.ingest.folder import SKIP_NO_ROW, FolderSource, natural_key, time_from_name
from ravenmem.ingest.poses import SKIP_OUTSIDE


def _img(path: Path, value: int) -> None:
    Image.fromarray(np.full((6, 8, 3), value, np.uint8)).save(path)


def test_times_from_file_names_and_interpolated_poses(tmp_path: Path) -> None:
    for i, t in enumerate([1000.5, 1000.25, 1001.0, 1003.0]):
        _img(tmp_path / f"{t:.6f}.jpg", 50 * i)
    (tmp_path / "poses.csv").write_text("t,x,y,yaw\n1000.0,0,0,0\n1002.0,2,4,1\n")
    src = FolderSource(tmp_path)  # poses.csv found in the folder
    frames = list(src)
    assert [f.t for f in frames] == [1000.25, 1000.5, 1001.0]  # time order, not name order
    p = frames[0].pose
    assert p is not None and (p.x, p.y, p.yaw) == pytest.approx((0.25, 0.5, 0.125))
    assert src.stats.skipped == {SKIP_OUTSIDE: 1} and src.stats.frames_seen == 4
    assert frames[0].image.shape == (6, 8, 3) and src.stats.raw_bytes == 3 * 6 * 8 * 3
    assert frames[0].path == str(tmp_path / "1000.250000.jpg")


def test_per_image_rows_with_times(tmp_path: Path) -> None:
    for name in ("b.png", "a.png", "c.png"):
        _img(tmp_path / name, 10)
    (tmp_path / "broken.png").write_bytes(b"\x89PNG garbage")
    poses = tmp_path / "track.txt"
    poses.write_text(
        "# per image\nfilename t x y z qx qy qz qw\nb.png 5.0 1 2 3 0 0 0 1\n"
        "a.png 6.0 4 5 6 0 0 0 1\nbroken.png 7.0 0 0 0 0 0 0 1\n"
    )
    src = FolderSource(tmp_path, poses=poses)
    frames = list(src)
    assert [(f.t, f.pose.x if f.pose else None) for f in frames] == [(5.0, 1.0), (6.0, 4.0)]
    assert src.stats.skipped == {SKIP_BAD_IMAGE: 1, SKIP_NO_ROW: 1}


def test_fps_scheme_uses_natural_name_order(tmp_path: Path) -> None:
    for i in (1, 2, 10):
        _img(tmp_path / f"frame_{i}.png", i)
    (tmp_path / "poses.csv").write_text("file,x,y\nframe_1.png,0,0\nframe_2.png,1,0\nframe_10.png,2,0\n")
    frames = list(FolderSource(tmp_path, fps=2.0, start_time=100.0))
    assert [f.t for f in frames] == [100.0, 100.5, 101.0]
    assert [f.pose.x for f in frames if f.pose] == [0.0, 1.0, 2.0]
    tracked = tmp_path / "track.csv"
    tracked.write_text("100,0,0,0\n102,4,0,0\n")
    frames = list(FolderSource(tmp_path, poses=tracked, fps=2.0, start_time=100.0))
    assert [f.pose.x for f in frames if f.pose] == pytest.approx([0.0, 1.0, 2.0])


def test_name_helpers() -> None:
    assert sorted(["f10.png", "f2.png", "f1.png"], key=natural_key) == ["f1.png", "f2.png", "f10.png"]
    assert time_from_name("1305031229.528748.jpg") == pytest.approx(1305031229.528748)
    assert time_from_name("1305031229528748000.png") == pytest.approx(1305031229.528748)  # ns
    assert time_from_name("1305031229528748.png") == pytest.approx(1305031229.528748)  # us
    assert time_from_name("1305031229528.png") == pytest.approx(1305031229.528)  # ms
    assert time_from_name("frame_001.png") is None


def test_folder_errors(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="no pose file"):
        _img(tmp_path / "frame_a.png", 1)
        FolderSource(tmp_path)
    (tmp_path / "poses.csv").write_text("0,0,0,0\n1,1,1,1\n")
    with pytest.raises(InputError, match=r"frame_a\.png: cannot tell the image's time from its name"):
        FolderSource(tmp_path)
    (tmp_path / "poses.csv").write_text("file,x,y\nframe_a.png,0,0\nframe_a.png,1,1\n")
    with pytest.raises(InputError, match=r"poses\.csv line 3, column 'file': 'frame_a\.png' listed twice"):
        FolderSource(tmp_path, fps=1.0)
    empty = tmp_path / "empty"
    empty.mkdir()
    (empty / "poses.csv").write_text("0,0,0,0\n")
    with pytest.raises(InputError, match="no images"):
        FolderSource(empty)
