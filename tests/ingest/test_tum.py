"""TUM RGB-D source on the real fr1_rpy sequence and on a small synthetic folder with depth."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from ravenmem.errors import InputError
from ravenmem.ingest.common import SKIP_BAD_IMAGE, SKIP_MISSING_IMAGE
from ravenmem.ingest.poses import SKIP_GAP, SKIP_OUTSIDE
from ravenmem.ingest.tum import TumSource


def test_real_sequence_nearest_ground_truth(tum_path: Path) -> None:
    gt = np.loadtxt(tum_path / "groundtruth.txt", comments="#")
    rgb = [ln.split() for ln in (tum_path / "rgb.txt").read_text().splitlines() if not ln.startswith("#")]
    src = TumSource(tum_path)
    frames = list(src)
    assert src.stats.frames_seen == len(rgb) == 723
    # three frames fall in ground-truth dropouts (0.06 s and 0.13 s gaps): none within 0.02 s
    assert len(frames) == 720 and src.stats.skipped == {SKIP_GAP: 3}
    for f in frames[::7]:
        assert f.image.shape == (480, 640, 3) and f.image.dtype == np.uint8 and f.image.flags.writeable
        row = gt[np.argmin(np.abs(gt[:, 0] - f.t))]
        assert abs(row[0] - f.t) <= 0.02
        assert f.pose is not None and (f.pose.x, f.pose.y, f.pose.z) == pytest.approx(tuple(row[1:4]))
        q = np.asarray(f.pose.quat)
        assert abs(abs(float(q @ (row[4:8] / np.linalg.norm(row[4:8])))) - 1.0) < 1e-9
        assert f.t == float(rgb[f.index][0]) and f.path == str(tum_path / rgb[f.index][1])
    assert src.stats.raw_bytes == 720 * 640 * 480 * 3
    assert all(a.t < b.t for a, b in zip(frames, frames[1:], strict=False))


def test_real_sequence_interpolated_keeps_all(tum_path: Path) -> None:
    src = TumSource(tum_path, pose_match="interpolate", max_gap=0.2)
    n = sum(1 for _ in src)
    assert n == 723 and src.stats.skipped == {}


def _png_depth(path: Path, metres: np.ndarray) -> None:
    Image.fromarray((metres * 5000).astype(np.uint16)).save(path)


@pytest.fixture()
def small_tum(tmp_path: Path) -> Path:
    (tmp_path / "rgb").mkdir()
    (tmp_path / "depth").mkdir()
    lines, dlines = ["# timestamp filename"], ["# timestamp filename"]
    for i in range(6):
        t = 100.0 + i * 0.1
        name = f"rgb/{t:.6f}.png"
        if i != 3:  # frame 3 is listed but missing
            Image.fromarray(np.full((4, 5, 3), 40 * i, np.uint8)).save(tmp_path / name)
        lines.append(f"{t:.6f} {name}")
        dname = f"depth/{t + 0.005:.6f}.png"
        d = np.full((4, 5), 1.5)
        d[0, 0] = 0.0
        _png_depth(tmp_path / dname, d)
        dlines.append(f"{t + 0.005:.6f} {dname}")
    (tmp_path / "rgb" / "broken.png").write_bytes(b"not a png")
    lines.append("100.55 rgb/broken.png")
    lines.append("200.0 rgb/100.000000.png")  # after the ground truth ends
    (tmp_path / "rgb.txt").write_text("\n".join(lines) + "\n")
    (tmp_path / "depth.txt").write_text("\n".join(dlines) + "\n")
    gt = [f"{100.0 + k * 0.01:.4f} {k * 0.01:.4f} 0 0 0 0 0 1" for k in range(0, 61)]
    (tmp_path / "groundtruth.txt").write_text("\n".join(gt) + "\n")
    return tmp_path


def test_skips_are_counted_and_depth_is_metres(small_tum: Path) -> None:
    src = TumSource(small_tum)
    frames = list(src)
    assert [f.index for f in frames] == [0, 1, 2, 4, 5]
    assert src.stats.skipped == {SKIP_MISSING_IMAGE: 1, SKIP_BAD_IMAGE: 1, SKIP_OUTSIDE: 1}
    f = frames[2]
    assert f.pose is not None and f.pose.x == pytest.approx(0.2)
    assert f.depth is not None and f.depth.dtype == np.float32
    assert f.depth[1, 1] == pytest.approx(1.5) and np.isnan(f.depth[0, 0])
    assert int(f.image[0, 0, 0]) == 80
    no_depth = list(TumSource(small_tum, depth=False))
    assert all(fr.depth is None for fr in no_depth)


def test_bad_tum_inputs(tmp_path: Path, small_tum: Path) -> None:
    with pytest.raises(InputError, match="no rgb.txt"):
        TumSource(tmp_path / "rgb")
    (small_tum / "rgb.txt").write_text("100.0 rgb/a.png\nabc rgb/b.png\n")
    with pytest.raises(InputError, match=r"rgb\.txt line 2, column 'timestamp': not a number: 'abc'"):
        TumSource(small_tum)
    (small_tum / "rgb.txt").write_text("100.0\n")
    with pytest.raises(InputError, match=r"rgb\.txt line 1: expected 'timestamp filename'"):
        TumSource(small_tum)
    (small_tum / "rgb.txt").write_text("100.0 rgb/a.png\n")
    (small_tum / "groundtruth.txt").unlink()
    with pytest.raises(InputError, match="no groundtruth.txt"):
        TumSource(small_tum)
