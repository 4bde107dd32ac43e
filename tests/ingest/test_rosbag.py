"""ROS bag source on bags written here: ROS 1, ROS 2 sqlite3 and ROS 2 MCAP (see bags.py)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from ravenmem.errors import InputError
from ravenmem.ingest.poses import SKIP_OUTSIDE
from ravenmem.ros.bag import RosbagSource
from ravenmem.ros.msgs import SKIP_COMPRESSED

from .bags import BAG_DELAY, RGB, write_bag

KINDS = ["ros1", "sqlite3", "mcap"]
IMAGES = "/camera/image_raw"
# times of the yielded raw images in bag order: the 6 supported encodings with the zero-stamp frame
# (bag time 10.45 + BAG_DELAY) received between; the yuv422 (10.6) and late (10.9) frames are skipped
RAW_TIMES = [10.0, 10.1, 10.2, 10.3, 10.4, 10.45 + BAG_DELAY, 10.5]
RAW_PIXELS = [RGB, RGB, (120,) * 3, RGB, RGB, RGB, (63, 63, 63)]


@pytest.fixture(scope="module", params=KINDS)
def bag(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory) -> Path:
    kind = request.param
    d = tmp_path_factory.mktemp(kind)
    return write_bag(d / ("rec.bag" if kind == "ros1" else "rec"), kind)


def _odom_pose_ok(f: object, t: float) -> None:
    pose = f.pose  # type: ignore[attr-defined]
    assert pose is not None
    assert (pose.x, pose.y, pose.yaw) == pytest.approx((t - 10, 0.0, 0.5 * (t - 10)), abs=1e-9)


def test_topic_auto_pick_lists_candidates(bag: Path) -> None:
    with pytest.raises(InputError) as e:
        RosbagSource(bag)
    msg = str(e.value)
    assert "several image topics" in msg and "/camera/compressed (sensor_msgs/msg/CompressedImage)" in msg
    assert "image_topic=TOPIC" in msg
    with pytest.raises(InputError) as e:
        RosbagSource(bag, image_topic=IMAGES)
    assert "several pose topics" in str(e.value) and "/odom (nav_msgs/msg/Odometry)" in str(e.value)
    with pytest.raises(InputError, match="image topic '/nope' not in the bag"):
        RosbagSource(bag, image_topic="/nope", pose_topic="/odom")


@pytest.mark.parametrize("pose_topic", ["/odom", "/pose", "/amcl_pose"])
def test_raw_images_with_interpolated_poses(bag: Path, pose_topic: str) -> None:
    src = RosbagSource(bag, image_topic=IMAGES, pose_topic=pose_topic)
    frames = list(src)
    assert [f.t for f in frames] == pytest.approx(RAW_TIMES)
    for f, px in zip(frames, RAW_PIXELS, strict=True):
        assert f.image.shape == (4, 6, 3) and f.image.dtype == np.uint8 and f.image.flags.writeable
        assert tuple(int(v) for v in f.image[1, 2]) == px
        _odom_pose_ok(f, f.t)
    assert frames[-1].image[0, 1].tolist() == [255, 255, 255]  # mono16 4000 of max 4000
    assert src.stats.frames_seen == 9 and src.stats.frames_yielded == 7
    assert src.stats.skipped == {"unsupported encoding 'yuv422'": 1, SKIP_OUTSIDE: 1}
    assert src.stats.raw_bytes == 9 * 4 * 6 * 3  # every raw image message, decoded or not


def test_compressed_images_with_tf_chain(bag: Path) -> None:
    src = RosbagSource(bag, image_topic="/camera/compressed", pose_topic="/tf")
    frames = list(src)
    assert src.tf_frames == ("map", "base_link")  # parent picked automatically
    assert [f.t for f in frames] == pytest.approx([10.05, 10.15])
    assert src.stats.skipped == {SKIP_COMPRESSED: 1}
    for f in frames:
        assert np.abs(f.image.astype(int) - RGB).max() <= 3  # jpeg is lossy, png exact
        x = f.t - 10
        # map -> odom is (1, 0, 0) turned 90 deg; odom -> base_link moves x along odom's x
        assert f.pose is not None
        assert (f.pose.x, f.pose.y, f.pose.z) == pytest.approx((1.0, x, 0.0), abs=1e-9)
        assert f.pose.yaw == pytest.approx(math.pi / 2 + 0.5 * x)
    direct = list(RosbagSource(bag, image_topic="/camera/compressed", pose_topic="/tf", tf_parent="odom"))
    assert direct[0].pose is not None and direct[0].pose.x == pytest.approx(0.05)
    # the inverse direction goes through the common ancestor: odom seen from base_link
    inv = list(
        RosbagSource(
            bag, image_topic="/camera/compressed", pose_topic="/tf", tf_parent="base_link", tf_child="odom"
        )
    )
    assert inv[0].pose is not None and inv[0].pose.yaw == pytest.approx(-0.025)
    with pytest.raises(InputError, match="frame 'camera' not in /tf"):
        RosbagSource(bag, image_topic="/camera/compressed", pose_topic="/tf", tf_child="camera")


def test_bag_receive_time_option(bag: Path) -> None:
    frames = list(RosbagSource(bag, image_topic=IMAGES, pose_topic="/odom", time_source="receive"))
    bag_times = [10.0, 10.1, 10.2, 10.3, 10.4, 10.45, 10.5]
    assert [f.t for f in frames] == pytest.approx([t + BAG_DELAY for t in bag_times])
    for f, t in zip(frames, bag_times, strict=True):
        _odom_pose_ok(f, t)  # poses use the odometry's receive times too


def test_single_candidates_are_picked_and_tf_is_the_fallback(tmp_path: Path) -> None:
    for kind in KINDS:
        p = write_bag(
            tmp_path / f"{kind}.bag" if kind == "ros1" else tmp_path / kind,
            kind,
            only={IMAGES, "/tf", "/tf_static"},
        )
        src = RosbagSource(p)
        assert src.image_topic == IMAGES and src.pose_topic == "/tf"
        assert sum(1 for _ in src) == len(RAW_TIMES)  # all inside the tf span (9.95 .. 10.75)


def test_unreadable_bag_is_clear_error(tmp_path: Path) -> None:
    junk = tmp_path / "junk.bag"
    junk.write_bytes(b"#ROSBAG V2.0\n garbage")
    with pytest.raises(InputError, match=r"junk\.bag: not a readable ROS bag"):
        RosbagSource(junk)
    with pytest.raises(InputError, match="ROS bag not found"):
        RosbagSource(tmp_path / "missing.bag")
    p = write_bag(tmp_path / "noposes", "mcap", only={IMAGES})
    with pytest.raises(InputError, match="bag has no pose topics"):
        RosbagSource(p)
