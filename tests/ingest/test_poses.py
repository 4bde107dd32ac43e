"""Pose files: layouts, exact error messages, interpolation (linear, slerp, yaw wrap), nearest."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation, Slerp

from ravenmem.errors import InputError
from ravenmem.ingest.poses import SKIP_GAP, SKIP_OUTSIDE, PoseTrack, load_pose_track, read_pose_table


def _write(tmp_path: Path, text: str, name: str = "poses.csv") -> Path:
    p = tmp_path / name
    p.write_text(text)
    return p


def test_csv_without_header_by_column_count(tmp_path: Path) -> None:
    tr = load_pose_track(_write(tmp_path, "# comment\n0,1,2,3\n\n1,2,4,6  # trailing comment\n"))
    assert tr.rotation == "none" and len(tr) == 2
    p = tr.interpolate(0.5)
    assert p is not None and (p.x, p.y, p.z, p.yaw) == pytest.approx((1.5, 3.0, 4.5, 0.0))
    assert p.quat is None


def test_csv_yaw_and_quaternion_layouts(tmp_path: Path) -> None:
    yaw = load_pose_track(_write(tmp_path, "0,0,0,0,0.5\n2,2,0,0,1.5\n"))
    assert yaw.rotation == "yaw"
    p = yaw.interpolate(1.0)
    assert p is not None and p.yaw == pytest.approx(1.0) and p.x == pytest.approx(1.0)
    quat = load_pose_track(_write(tmp_path, "0,0,0,0,0,0,0,2\n1,1,0,0,0,0,0,1\n", "q.csv"))
    assert quat.rotation == "quat"
    p = quat.interpolate(0.0)
    assert p is not None and p.quat == pytest.approx((0, 0, 0, 1))  # normalised


def test_header_by_name_any_order_and_optional_z(tmp_path: Path) -> None:
    text = "heading,y,timestamp,x,extra\n0.1,2,10,1,foo\n0.3,4,11,3,bar\n"
    tr = load_pose_track(_write(tmp_path, text))
    assert tr.span == (10.0, 11.0)
    p = tr.interpolate(10.5)
    assert p is not None and (p.x, p.y, p.z, p.yaw) == pytest.approx((2.0, 3.0, 0.0, 0.2))


def test_tum_layout_space_separated(tmp_path: Path) -> None:
    s = math.sqrt(0.5)
    text = f"# timestamp tx ty tz qx qy qz qw\n100.0 1 2 3 0 0 0 1\n100.1 1 2 3 0 0 {s:f} {s:f}\n"
    tr = load_pose_track(_write(tmp_path, text, "groundtruth.txt"))
    p = tr.pose_at(1)
    assert p.yaw == pytest.approx(math.pi / 2) and p.quat is not None


def test_file_column_table(tmp_path: Path) -> None:
    tb = read_pose_table(_write(tmp_path, "file,x,y,yaw\na.jpg,1,2,0.5\nb.jpg,3,4,0.6\n"))
    assert tb.files == ["a.jpg", "b.jpg"] and tb.t is None
    with pytest.raises(InputError, match="no time column"):
        PoseTrack.from_table(tb)


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("0,0,0,0\n1,0,abc,0\n", "line 2, column 'y': not a number: 'abc'"),
        ("t,x,y,z\n0,0,0,0\n1,0,0,nan\n", "line 3, column 'z': not a finite number: 'nan'"),
        ("0,0,0,0\n1,0,0\n", "line 2: expected 4 columns, found 3"),
        ("0,0,0\n", "line 1: 3 columns without a header"),
        ("# only comments\n", "no pose rows found"),
        ("t,x,y\n0,0,0\n2,1,1\n1,2,2\n", "line 4, column 't': timestamp 1.0 is not after 2.0 on line 3"),
        ("0,0,0,0\n0,1,1,1\n", "line 2, column 't': timestamp 0.0 is not after 0.0 on line 1"),
        ("time,x,qx,qy\n0,0,0,0\n", "line 1: header 'time,x,qx,qy' has no column for y"),
        ("t,x,y,qx,qy,qz\n", "a quaternion needs all of qx, qy, qz, qw"),
        ("0,0,0,0,0,0,0,0\n", "line 1, columns qx..qw: quaternion has zero norm"),
        ("t,x,y,x\n", "column 'x' appears twice"),
    ],
)
def test_bad_input_names_file_line_and_field(tmp_path: Path, text: str, message: str) -> None:
    p = _write(tmp_path, text)
    with pytest.raises(InputError) as e:
        load_pose_track(p)
    assert str(e.value).startswith(str(p))
    assert message in str(e.value)


def test_missing_file_is_input_error(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="pose file .*nope.csv does not exist"):
        load_pose_track(tmp_path / "nope.csv")


def test_sort_option_sorts_and_drops_repeats(tmp_path: Path) -> None:
    tr = load_pose_track(_write(tmp_path, "2,2,0,0\n0,0,0,0\n1,9,0,0\n1,1,0,0\n"), sort=True)
    assert list(tr.t) == [0.0, 1.0, 2.0]
    assert list(tr.xyz[:, 0]) == [0.0, 1.0, 2.0]  # the later row of the repeated time wins


def test_slerp_midpoint_matches_scipy_and_is_unit() -> None:
    r0 = Rotation.from_euler("xyz", [0.2, -0.1, 0.3])
    r1 = Rotation.from_euler("xyz", [0.5, 0.4, -1.2])
    tr = PoseTrack([0.0, 2.0], [[0, 0, 0], [2, 4, -2]], quat=np.stack([r0.as_quat(), r1.as_quat()]))
    p = tr.interpolate(1.0)
    assert p is not None and p.quat is not None
    want = r0 * Rotation.from_rotvec((r0.inv() * r1).as_rotvec() / 2)
    assert (Rotation.from_quat(p.quat) * want.inv()).magnitude() < 1e-9
    assert (p.x, p.y, p.z) == pytest.approx((1.0, 2.0, -1.0))
    # the midpoint is equally far (in angle) from both ends
    a0 = (Rotation.from_quat(p.quat) * r0.inv()).magnitude()
    a1 = (Rotation.from_quat(p.quat) * r1.inv()).magnitude()
    assert a0 == pytest.approx(a1)


def test_track_slerp_matches_scipy_on_random_rotations() -> None:
    rng = np.random.default_rng(3)
    t = np.cumsum(rng.uniform(0.01, 0.2, 200))
    rots = Rotation.random(200, random_state=4)
    quats = rots.as_quat() * rng.choice([-1.0, 1.0], (200, 1))  # random signs must not matter
    tr = PoseTrack(t, rng.normal(size=(200, 3)), quat=quats)
    q = rng.uniform(t[0], t[-1], 5000)
    valid, _, yaw, got = tr.interpolate_many(q)
    want = Slerp(t, rots)(q)
    assert valid.all() and got is not None
    assert (Rotation.from_quat(got) * want.inv()).magnitude().max() < 1e-9
    assert np.allclose(yaw, want.as_euler("ZYX")[:, 0])
    for i in range(0, 5000, 50):  # the one-at-a-time path gives the same poses
        p = tr.interpolate(float(q[i]))
        assert p is not None and p.quat is not None
        assert abs(abs(float(np.dot(p.quat, got[i]))) - 1.0) < 1e-12 and p.yaw == pytest.approx(yaw[i])


def test_slerp_takes_the_short_way_with_flipped_quaternion_sign() -> None:
    q0 = Rotation.from_euler("z", 0.1).as_quat()
    q1 = -Rotation.from_euler("z", 0.3).as_quat()  # same rotation, opposite sign
    tr = PoseTrack([0.0, 1.0], [[0, 0, 0], [0, 0, 0]], quat=np.stack([q0, q1]))
    p = tr.interpolate(0.5)
    assert p is not None and p.yaw == pytest.approx(0.2)


def test_yaw_interpolates_across_the_wrap() -> None:
    tr = PoseTrack([0.0, 1.0], [[0, 0, 0], [1, 0, 0]], yaw=[math.pi - 0.1, -math.pi + 0.1])
    p = tr.interpolate(0.5)
    assert p is not None and abs(abs(p.yaw) - math.pi) < 1e-9
    q = tr.interpolate(0.25)
    assert q is not None and q.yaw == pytest.approx(math.pi - 0.05)
    r = tr.interpolate(0.75)
    assert r is not None and r.yaw == pytest.approx(-math.pi + 0.05)


def test_outside_span_and_gap_reasons() -> None:
    tr = PoseTrack([0.0, 1.0, 5.0], [[0, 0, 0], [1, 0, 0], [5, 0, 0]], yaw=[0, 0, 0])
    assert tr.interpolate(-0.01) is None and tr.interpolate(5.01) is None
    assert tr.interpolate(3.0) is not None  # no limit by default
    assert tr.interpolate(3.0, max_gap=2.0) is None
    assert tr.interpolate(5.0, max_gap=2.0) is not None  # exactly on a sample
    assert tr.match(-1.0) == SKIP_OUTSIDE
    assert tr.match(3.0, max_gap=2.0) == SKIP_GAP
    assert tr.match(3.0, "nearest", max_gap=0.5) == SKIP_GAP
    assert tr.match(5.3, "nearest", max_gap=0.5) != SKIP_OUTSIDE  # within max_gap of the end
    assert tr.match(5.6, "nearest", max_gap=0.5) == SKIP_OUTSIDE


def test_nearest_and_vectorised_lookups() -> None:
    t = np.arange(0.0, 10.0, 0.01)
    xyz = np.stack([t, 2 * t, np.zeros_like(t)], axis=1)
    tr = PoseTrack(t, xyz, yaw=np.sin(t))
    p = tr.nearest(3.004, max_gap=0.02)
    assert p is not None and p.x == pytest.approx(3.0)
    assert tr.nearest(3.006, max_gap=0.02) is not None and tr.nearest(11.0, max_gap=0.02) is None
    q = np.linspace(-1, 11, 1001)
    valid, pos, yaw, quat = tr.interpolate_many(q)
    inside = (q >= 0) & (q <= t[-1])
    assert (valid == inside).all() and quat is None
    assert np.allclose(pos[valid, 0], q[valid]) and np.allclose(pos[valid, 1], 2 * q[valid])
    assert np.isnan(pos[~valid]).all()
    for i in np.flatnonzero(valid)[::37]:  # one-at-a-time path agrees
        p1 = tr.interpolate(float(q[i]))
        assert p1 is not None and (p1.x, p1.y, p1.yaw) == pytest.approx((pos[i, 0], pos[i, 1], yaw[i]))
    idx = tr.nearest_index_many(q, max_gap=0.005)
    near = (q >= -0.005) & (q <= t[-1] + 0.005)
    assert (idx[~near] == -1).all() and (idx[near] >= 0).all()
    assert np.abs(t[idx[near]] - q[near]).max() <= 0.005 + 1e-12


def test_single_sample_track() -> None:
    tr = PoseTrack([1.0], [[1, 2, 3]], yaw=[0.5])
    assert tr.interpolate(1.0) == tr.pose_at(0)
    assert tr.interpolate(1.1) is None
