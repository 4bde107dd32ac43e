"""Building a memory's map afterwards from the recordings it came from (`ravenmem map` on a
memory ingested without one): read again, every depth frame, once."""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image
from scipy.spatial.transform import Rotation

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "nav"))

from depthscene import INTR, look, render  # noqa: E402

import ravenmem  # noqa: E402
from ravenmem.errors import InputError  # noqa: E402
from ravenmem.ingest.pipeline import ingest  # noqa: E402
from ravenmem.ingest.tum import TumSource  # noqa: E402
from ravenmem.nav import load_map  # noqa: E402
from ravenmem.robot.maps import build_map  # noqa: E402


def _tum(root: Path, n: int = 10) -> Path:
    """A TUM folder (optical-frame ground truth, depth at 5000 per metre) of a walk to a wall."""
    (root / "rgb").mkdir(parents=True)
    (root / "depth").mkdir()
    rgb, dep, gt = [], [], []
    for i in range(n):
        t = 1000.0 + i
        cam = look(0.15 * i, 0.0, 1.1, 0.2 * math.sin(i), math.radians(20))
        Image.fromarray(np.full((INTR.height, INTR.width, 3), 10 * i, np.uint8)).save(
            root / "rgb" / f"{t}.png"
        )
        Image.fromarray(np.round(render(cam, [(3.5, -4, 3.7, 4, 2.5)]) * 5000).astype(np.uint16)).save(
            root / "depth" / f"{t}.png"
        )
        rgb.append(f"{t} rgb/{t}.png")
        dep.append(f"{t} depth/{t}.png")
        q = Rotation.from_matrix(cam[:3, :3]).as_quat()
        gt.append(f"{t} {cam[0, 3]} {cam[1, 3]} {cam[2, 3]} {q[0]} {q[1]} {q[2]} {q[3]}")
    for name, rows in (("rgb.txt", rgb), ("depth.txt", dep), ("groundtruth.txt", gt)):
        (root / name).write_text("\n".join(rows) + "\n")
    return root


def test_map_built_later_from_the_recording(tmp_path: Path, color_embedder) -> None:
    rec = _tum(tmp_path / "walk")
    mem = ravenmem.create(tmp_path / "m.mem", embedder=color_embedder, ocr=False, thumb_size=0)
    ingest(TumSource(rec), mem)  # no mapper: no map
    assert not (mem.path / "map.npz").exists()
    with pytest.raises(InputError, match="no recording to build one from"):
        build_map(mem)
    with pytest.raises(InputError, match="no map could be built.*10 no camera intrinsics"):
        build_map(mem, recordings=[rec])  # the camera is unknown (no fr1/fr2/fr3 in the name): said
    grid, rep = build_map(mem, intrinsics="200,200,160,120", recordings=[rec])
    assert rep["recordings"][str(rec)]["frames_mapped"] == 10
    assert grid.kind == "recorded" and grid.occupied[grid.world_to_cell(3.51, 0.0)]
    assert grid.free[grid.world_to_cell(2.5, 0.0)]
    _, again = build_map(mem, intrinsics="200,200,160,120")  # a refresh, from the map's own list
    assert again["recordings"][str(rec)]["frames_mapped"] == 0
    before = load_map(mem.path).logodds.copy()
    grid2, rebuilt = build_map(mem, intrinsics="200,200,160,120", rebuild=True)
    assert rebuilt["recordings"][str(rec)]["frames_mapped"] == 10
    assert np.array_equal(grid2.logodds, before)  # the same frames give the same map
    other = _tum(tmp_path / "elsewhere", n=3)
    (other / "rgb.txt").write_text((other / "rgb.txt").read_text() + "# another recording\n")
    with pytest.raises(InputError, match="not a recording of"):
        build_map(mem, intrinsics="200,200,160,120", recordings=[other])
