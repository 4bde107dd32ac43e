"""open_source: format detection from the path, explicit formats, clear errors."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from ravenmem.errors import InputError
from ravenmem.ingest import SOURCES, FrameSource
from ravenmem.ingest.folder import FolderSource
from ravenmem.ingest.sources import detect_format, open_source
from ravenmem.ingest.tum import TumSource
from ravenmem.ingest.video import VideoSource
from ravenmem.ros.bag import RosbagSource

from .bags import write_bag
from .test_video import write_video


def test_all_formats_registered() -> None:
    import ravenmem.ingest.sources  # noqa: F401

    assert {"video", "tum", "folder", "rosbag"} <= set(SOURCES.names())


def test_detects_each_format(tmp_path: Path, tum_path: Path) -> None:
    src = open_source(tum_path)
    assert isinstance(src, TumSource) and isinstance(src, FrameSource)

    vid = tmp_path / "clip.MP4"
    write_video(vid)
    poses = tmp_path / "p.csv"
    poses.write_text("0,0,0,0\n5,1,0,0\n")
    v = open_source(vid, poses=poses)
    assert isinstance(v, VideoSource) and len(list(v)) == 30

    imgs = tmp_path / "imgs"
    imgs.mkdir()
    Image.fromarray(np.zeros((4, 4, 3), np.uint8)).save(imgs / "1.5.png")
    (imgs / "poses.csv").write_text("0,0,0,0\n2,1,0,0\n")
    f = open_source(imgs)
    assert isinstance(f, FolderSource) and [fr.t for fr in f] == [1.5]

    bag1 = write_bag(tmp_path / "r.bag", "ros1", only={"/camera/image_raw", "/odom"})
    ros2 = write_bag(tmp_path / "r2", "mcap", only={"/camera/image_raw", "/odom"})
    for p in (bag1, ros2):
        assert detect_format(p) == ("rosbag", p)
        assert isinstance(open_source(p), RosbagSource)
    # a bare MCAP file, alone in a folder without metadata.yaml
    (ros2 / "metadata.yaml").unlink()
    fmt, inner = detect_format(ros2)
    assert fmt == "rosbag" and inner.suffix == ".mcap"
    assert len(list(open_source(ros2))) == 7


def test_explicit_format_and_errors(tmp_path: Path) -> None:
    (tmp_path / "notes.txt").write_text("hi")
    with pytest.raises(InputError, match=r"notes\.txt: unknown file type '\.txt'; expected one of \.mp4"):
        open_source(tmp_path / "notes.txt")
    with pytest.raises(InputError, match="no such file or folder"):
        open_source(tmp_path / "nothing")
    with pytest.raises(InputError, match="cannot tell the format"):
        open_source(tmp_path)
    with pytest.raises(InputError, match="unknown source format 'gopro'; choose one of: folder, rosbag"):
        open_source(tmp_path, format="gopro")
    with pytest.raises(InputError, match="not a TUM RGB-D folder"):
        open_source(tmp_path, format="tum")


def test_unknown_option_is_named(tmp_path: Path, tum_path: Path) -> None:
    with pytest.raises(InputError, match="tum source has no option image_topic; options: groundtruth"):
        open_source(tum_path, image_topic="/cam")
    # `poses` is accepted by every file source (TUM: instead of groundtruth.txt)
    gt = tmp_path / "gt.csv"
    gt.write_text("t,x,y\n1305031229.0,0,0\n1305031230.0,1,0\n")
    src = open_source(tum_path, poses=gt, pose_match="interpolate", max_gap=None)
    assert isinstance(src, TumSource) and src.track.span == (1305031229.0, 1305031230.0)


def test_each_source_has_a_typed_config_checked_before_any_file_is_read(
    tmp_path: Path, tum_path: Path
) -> None:
    from ravenmem.ingest.folder import FolderConfig
    from ravenmem.ingest.tum import TumConfig
    from ravenmem.ingest.video import VideoConfig
    from ravenmem.ros.bag import RosbagConfig

    gone = tmp_path / "not-there"  # the values are wrong before the path is looked at
    for make, message in (
        (lambda: TumConfig(gone, max_gap=-1.0), "tum: max_gap must be >= 0 seconds"),
        (lambda: TumConfig(gone, max_gap=None), "nearest pose matching needs max_gap"),
        (lambda: TumConfig(gone, depth="yes"), "tum: depth must be true or false"),
        (lambda: FolderConfig(gone, fps=0), "folder: fps must be > 0"),
        (lambda: FolderConfig(gone, depth_scale=float("nan")), "depth_scale must be a finite number"),
        (lambda: FolderConfig(gone, camera_frame="up"), "camera_frame must be 'body' or 'optical'"),
        (lambda: VideoConfig(gone, pose_match="best"), "unknown pose matching 'best'"),
        (lambda: RosbagConfig(gone, time_source="wall"), "time_source must be 'header' or 'receive'"),
        (lambda: RosbagConfig(gone, intrinsics="fr9"), "preset"),
        (lambda: open_source(gone, "folder", fps=-2), "folder: fps must be > 0"),
    ):
        with pytest.raises(InputError, match=message):
            make()
    # defaults that depend on other options are settled in the config
    assert VideoConfig(gone, pose_match="nearest").max_gap == 0.05
    assert FolderConfig(gone).max_gap is None
    # a config opens its source (with options changed on the way), through the registry too
    cfg = TumConfig(tum_path, depth=False)
    src = open_source(cfg)
    assert isinstance(src, TumSource) and src.config is cfg and src.depth_entries == []
    assert open_source(cfg, max_gap=0.05).max_gap == 0.05
    assert isinstance(SOURCES.create(f"tum:{tum_path}", depth=False), TumSource)
    with pytest.raises(InputError, match="a tum config cannot open a folder source"):
        open_source(cfg, "folder")
    with pytest.raises(InputError, match="tum source has no option fps; options: groundtruth"):
        open_source(cfg, fps=2.0)
