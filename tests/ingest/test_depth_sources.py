"""Depth from every source: TUM (presets by name), image folders with a depth folder, ROS bags
(16UC1 mm / 32FC1 m with camera_info and the camera mount from /tf_static); and the ingest
pipeline feeding every depth frame to the mapper, keyframe or not."""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image
from rosbags.rosbag2 import Writer
from scipy.spatial.transform import Rotation

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "nav"))

from bags import _Msgs, _typestore  # noqa: E402
from depthscene import INTR, look, render  # noqa: E402

import ravenmem  # noqa: E402
from ravenmem.errors import InputError  # noqa: E402
from ravenmem.ingest.depth import PRESETS, decode_depth_message, parse_intrinsics, preset_from_name  # noqa: E402
from ravenmem.ingest.folder import FolderSource  # noqa: E402
from ravenmem.ingest.keyframes import KeyframeConfig  # noqa: E402
from ravenmem.ingest.pipeline import ingest  # noqa: E402
from ravenmem.ingest.tum import TumSource  # noqa: E402
from ravenmem.nav.mapping import MapBuilder  # noqa: E402
from ravenmem.ros.bag import RosbagSource  # noqa: E402
from ravenmem.types import Intrinsics  # noqa: E402


def test_intrinsics_from_presets_and_numbers() -> None:
    assert parse_intrinsics("fr1") == Intrinsics(517.3, 516.5, 318.6, 255.3, 640, 480)
    assert parse_intrinsics("Freiburg3") is PRESETS["fr3"] and parse_intrinsics("kinect").fx == 525.0
    assert parse_intrinsics("100, 110, 50.5, 40") == Intrinsics(100.0, 110.0, 50.5, 40.0)
    assert parse_intrinsics("1,2,3,4,64,48").width == 64
    for bad, msg in (("fr9", "preset"), ("1,2,3", "4 or 6"), ("0,1,2,3", "fx, fy must be > 0")):
        with pytest.raises(InputError, match=msg):
            parse_intrinsics(bad)
    assert preset_from_name("rgbd_dataset_freiburg2_pioneer_slam") is PRESETS["fr2"]
    assert preset_from_name("tum_fr1_rpy") is PRESETS["fr1"] and preset_from_name("office") is None
    # a 320x240 depth image of a 640x480 calibration: the camera scales with it
    half = PRESETS["fr1"].for_image(320, 240)
    assert (half.fx, half.cx, half.width) == pytest.approx((258.65, 159.3, 320))
    with pytest.raises(InputError, match="uniform resize"):
        PRESETS["fr1"].for_image(320, 100)


def test_tum_camera_from_the_folder_name(tmp_path: Path) -> None:
    root = tmp_path / "rgbd_dataset_freiburg3_long_office"
    (root / "rgb").mkdir(parents=True)
    Image.fromarray(np.zeros((4, 4, 3), np.uint8)).save(root / "rgb" / "1.png")
    (root / "rgb.txt").write_text("1.0 rgb/1.png\n")
    (root / "groundtruth.txt").write_text("1.0 0 0 0 0 0 0 1\n")
    src = TumSource(root)
    assert src.intrinsics is PRESETS["fr3"] and src.camera_extrinsic == "optical"
    assert TumSource(root, intrinsics="1,1,2,2").intrinsics == Intrinsics(1, 1, 2, 2)


def _folder(tmp_path: Path, n: int = 6, by: str = "stem") -> Path:
    root = tmp_path / "imgs"
    (root / "depth").mkdir(parents=True)
    rows = ["t,x,y,z,yaw"]
    for i in range(n):
        t = 10.0 + 0.1 * i
        Image.fromarray(np.full((6, 8, 3), 30 * i, np.uint8)).save(root / f"{t:.6f}.png")
        d = np.full((6, 8), 1500 + 100 * i, np.uint16)
        d[0, 0] = 0
        dname = f"{t:.6f}.png" if by == "stem" else f"{t + 0.004:.6f}.png"
        Image.fromarray(d).save(root / "depth" / dname)
        rows.append(f"{t},{0.1 * i},0,0.5,0")
    (root / "poses.csv").write_text("\n".join(rows) + "\n")
    return root


@pytest.mark.parametrize("by", ["stem", "time"])
def test_image_folder_with_a_depth_folder(tmp_path: Path, by: str) -> None:
    root = _folder(tmp_path, by=by)
    src = FolderSource(root, depth=root / "depth", intrinsics="fr1")
    frames = list(src)
    assert len(frames) == 6 and all(f.depth is not None for f in frames)
    assert frames[2].depth[3, 3] == pytest.approx(1.7) and np.isnan(frames[2].depth[0, 0])
    assert src.intrinsics is PRESETS["fr1"] and src.camera_extrinsic == "body"
    tum_scaled = list(FolderSource(root, depth=root / "depth", depth_scale=5000, camera_frame="optical"))
    assert tum_scaled[0].depth[3, 3] == pytest.approx(0.3)
    assert all(f.depth is None for f in FolderSource(root))  # no depth folder, no depth
    with pytest.raises(InputError, match="camera_frame"):
        FolderSource(root, camera_frame="sideways")
    (tmp_path / "empty").mkdir()
    with pytest.raises(InputError, match="no depth images"):
        FolderSource(root, depth=tmp_path / "empty")


def _scene_folder(root: Path, n: int) -> Path:
    """An image folder with a depth folder: a camera (optical-frame poses) walking towards a
    wall over a floor, depth in millimetres."""
    (root / "depth").mkdir(parents=True)
    rows = ["t,file,x,y,z,qx,qy,qz,qw"]
    for i in range(n):
        cam = look(0.1 * i, 0.05 * i, 1.0, 0.1 * math.sin(i), math.radians(15))
        d = render(cam, [(4.0, -3.0, 4.2, 3.0, 2.0)])
        name = f"{i:04d}.png"
        Image.fromarray(np.full((INTR.height, INTR.width, 3), 20 * i, np.uint8)).save(root / name)
        Image.fromarray(np.round(d * 1000).astype(np.uint16)).save(root / "depth" / name)
        q = Rotation.from_matrix(cam[:3, :3]).as_quat()
        x, y, z = cam[:3, 3]
        rows.append(f"{100 + 0.5 * i},{name},{x},{y},{z},{q[0]},{q[1]},{q[2]},{q[3]}")
    (root / "poses.csv").write_text("\n".join(rows) + "\n")
    return root


def test_pipeline_maps_every_depth_frame_not_only_keyframes(tmp_path: Path, color_embedder) -> None:
    root, intr = _scene_folder(tmp_path / "scene", n=12), INTR
    src = FolderSource(root, depth=root / "depth", camera_frame="optical")
    mem = ravenmem.create(tmp_path / "m.mem", embedder=color_embedder, ocr=False, thumb_size=0)
    mapper = MapBuilder(mem.path, intr, src.camera_extrinsic, fit_frames=4)
    rep = ingest(src, mem, keyframes=KeyframeConfig.only(stride=4), mapper=mapper)
    assert rep.kept == 3 and mapper.stats.mapped == 12
    grid = ravenmem.nav.load_map(mem.path)
    assert grid.occupied.sum() > 20 and grid.free.sum() > 200
    # a second ingest of the same recording adds memories but no frame twice to the map
    mapper2 = MapBuilder(mem.path, intr, "optical")
    ingest(FolderSource(root, depth=root / "depth", camera_frame="optical"), mem, mapper=mapper2)
    assert mapper2.stats.mapped == 0 and mapper2.stats.skipped == {"already in the map": 12}


def _bag(path: Path, enc: str) -> Path:
    """ROS 2 bag: colour at 10.0 + 0.1 i, depth 10 ms later, odom, camera_info, and the depth
    camera's optical frame 0.2 m ahead of base_link and 1 m up, in /tf_static."""
    ts = _typestore(False)
    m = _Msgs(ts, False)
    T = m.T
    h, w = 4, 6
    msgs: list[tuple[str, float, object]] = []
    for i in range(5):
        t = 10.0 + 0.1 * i
        rgb = np.tile(np.array([200, 100, 50], np.uint8), h * w)
        msgs.append(
            (
                "/camera/color/image_raw",
                t,
                T("sensor_msgs/msg/Image")(
                    header=m.header(t, "camera_color_optical_frame"),
                    height=h,
                    width=w,
                    encoding="rgb8",
                    is_bigendian=0,
                    step=w * 3,
                    data=rgb,
                ),
            )
        )
        metres = 1.0 + i
        raw = (
            np.full(h * w, int(metres * 1000), "<u2").view(np.uint8)
            if enc == "16UC1"
            else np.full(h * w, metres, "<f4").view(np.uint8)
        )
        msgs.append(
            (
                "/camera/depth/image_raw",
                t + 0.01,
                T("sensor_msgs/msg/Image")(
                    header=m.header(t + 0.01, "camera_depth_optical_frame"),
                    height=h,
                    width=w,
                    encoding=enc,
                    is_bigendian=0,
                    step=w * (2 if enc == "16UC1" else 4),
                    data=raw,
                ),
            )
        )
    for k in range(8):
        t = 9.95 + 0.1 * k
        msgs.append(("/odom", t, m.odom(t)))
    info = T("sensor_msgs/msg/CameraInfo")(
        header=m.header(10.0, "camera_depth_optical_frame"),
        height=h,
        width=w,
        distortion_model="plumb_bob",
        d=np.zeros(5),
        k=np.array([5.0, 0, 3.0, 0, 5.5, 2.0, 0, 0, 1]),
        r=np.eye(3).reshape(-1),
        p=np.zeros(12),
        binning_x=0,
        binning_y=0,
        roi=T("sensor_msgs/msg/RegionOfInterest")(
            x_offset=0, y_offset=0, height=0, width=0, do_rectify=False
        ),
    )
    msgs.append(("/camera/depth/camera_info", 10.0, info))
    q = Rotation.from_matrix([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]]).as_quat()
    tf = T("geometry_msgs/msg/TransformStamped")(
        header=m.header(9.0, "base_link"),
        child_frame_id="camera_depth_optical_frame",
        transform=T("geometry_msgs/msg/Transform")(
            translation=T("geometry_msgs/msg/Vector3")(x=0.2, y=0.0, z=1.0),
            rotation=T("geometry_msgs/msg/Quaternion")(x=q[0], y=q[1], z=q[2], w=q[3]),
        ),
    )
    msgs.append(("/tf_static", 9.0, T("tf2_msgs/msg/TFMessage")(transforms=[tf])))
    msgs.sort(key=lambda x: x[1])
    with Writer(path, version=9) as wr:
        conns = {}
        for topic, _, msg in msgs:
            if topic not in conns:
                conns[topic] = wr.add_connection(topic, msg.__msgtype__, typestore=ts)  # type: ignore[attr-defined]
        for topic, t, msg in msgs:
            wr.write(conns[topic], int(round(t * 1e9)), ts.serialize_cdr(msg, msg.__msgtype__))  # type: ignore[attr-defined]
    return path


@pytest.mark.parametrize("enc", ["16UC1", "32FC1"])
def test_bag_depth_camera_info_and_mount(tmp_path: Path, enc: str) -> None:
    src = RosbagSource(_bag(tmp_path / "b", enc), pose_topic="/odom")
    assert src.image_topic == "/camera/color/image_raw" and src.depth_topic == "/camera/depth/image_raw"
    assert src.camera_info_topic == "/camera/depth/camera_info"
    assert src.intrinsics == Intrinsics(5.0, 5.5, 3.0, 2.0, 6, 4)
    mount = np.asarray(src.camera_extrinsic)
    assert mount.shape == (4, 4) and mount[:3, 3] == pytest.approx([0.2, 0.0, 1.0])
    assert mount[:3, 2] == pytest.approx([1.0, 0.0, 0.0])  # the optical axis looks along base x
    frames = list(src)
    assert len(frames) == 5
    for i, f in enumerate(frames):
        assert f.depth is not None and f.depth.shape == (4, 6)
        assert float(np.nanmean(f.depth)) == pytest.approx(1.0 + i, abs=1e-3)  # the depth 10 ms later
    with pytest.raises(InputError, match="not a sensor_msgs/Image topic"):
        RosbagSource(tmp_path / "b", pose_topic="/odom", depth_topic="/odom")


def test_depth_message_errors_are_reasons() -> None:
    class Msg:
        encoding, height, width, step, is_bigendian = "bgr8", 2, 2, 6, 0
        data = np.zeros(12, np.uint8)

    assert "unsupported depth encoding" in decode_depth_message(Msg())
    Msg.encoding, Msg.step = "16UC1", 1
    assert decode_depth_message(Msg()) == "malformed depth message"
    Msg.step = 4
    Msg.data = np.array([0, 0, 232, 3, 208, 7, 0, 0], np.uint8)  # 0, 1000, 2000, 0 mm
    d = decode_depth_message(Msg())
    assert np.isnan(d[0, 0]) and d[0, 1] == pytest.approx(1.0) and d[1, 0] == pytest.approx(2.0)
    assert math.isnan(float(d[1, 1]))


def test_ingest_command_takes_the_folder_camera_frame_and_depth_scale(tmp_path: Path) -> None:
    """`ravenmem ingest FOLDER --depth D --camera-frame optical`: optical-frame poses (what a
    SLAM system writes) put the wall where it is; `--depth-scale` says what a 16-bit unit is."""
    from tests.cli.helpers import assert_one_line_error, run_cli

    root = _scene_folder(tmp_path / "scene", n=12)  # a wall at x = 4.0 .. 4.2 m, depth in mm
    args = [
        "--depth",
        str(root / "depth"),
        "--intrinsics",
        "200,200,160,120",
        "--no-ocr",
        "--keyframes",
        "all",
    ]

    def wall_x(mem: Path) -> np.ndarray:
        grid = ravenmem.nav.load_map(mem)
        _, cc = np.nonzero(grid.occupied)
        return grid.origin[0] + (cc + 0.5) * grid.resolution

    r = run_cli("ingest", str(root), "--memory", str(tmp_path / "o.mem"), "--camera-frame", "optical", *args)
    assert r.returncode == 0, r.stderr
    x = wall_x(tmp_path / "o.mem")
    assert len(x) > 20 and np.all((x > 3.85) & (x < 4.35))
    # the same millimetres read as 1/2000 m: every depth halves, the wall comes halfway closer
    cmd = ["ingest", str(root), "--memory", str(tmp_path / "h.mem"), "--camera-frame", "optical"]
    r = run_cli(*cmd, "--depth-scale", "2000", *args)
    assert r.returncode == 0, r.stderr
    x = wall_x(tmp_path / "h.mem")
    assert len(x) > 20 and 1.9 < np.median(x) < 2.7
    bad = run_cli(
        "ingest", str(root), "--memory", str(tmp_path / "b.mem"), "--camera-frame", "sideways", *args
    )
    assert "camera_frame must be 'body' or 'optical'" in assert_one_line_error(bad)
    assert not (tmp_path / "b.mem").exists()
