"""Nav2 interop: map_server YAML + PGM export/import (its exact conventions) and PoseStamped goals."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from ravenmem.errors import InputError
from ravenmem.nav.goals import pose_stamped, read_pose_stamped
from ravenmem.nav.grid import MapConfig, OccupancyGrid
from ravenmem.ros.nav2 import export_map_server, import_map_server
from tests.cli.helpers import run_cli


def _grid() -> OccupancyGrid:
    """5 x 4 cells of 0.1 m from (-1.0, 2.0): row 4 (the largest y) has an obstacle at col 0."""
    g = OccupancyGrid(MapConfig(resolution=0.1), origin=(-1.0, 2.0), shape=(5, 4))
    g.known[:, :3] = True  # column 3 unknown
    g.logodds[:, :3] = -2.0
    g.logodds[4, 0] = 3.0  # top-left in the picture
    g.logodds[0, 2] = 3.0  # bottom row
    return g


def test_export_follows_map_server_conventions(tmp_path: Path) -> None:
    yml, pgm = export_map_server(_grid(), tmp_path / "room.yaml")
    assert pgm == tmp_path / "room.pgm" and pgm.read_bytes()[:2] == b"P5"
    text = yml.read_text()
    for line in (
        "image: room.pgm",
        "mode: trinary",
        "resolution: 0.1",
        "origin: [-1.0, 2.0, 0.0]",
        "negate: 0",
        "occupied_thresh: 0.65",
        "free_thresh: 0.196",
    ):
        assert line in text.splitlines(), line
    with Image.open(pgm) as im:
        px = np.asarray(im)
    assert px.shape == (5, 4)
    assert px[0, 0] == 0  # row 0 of the image is the top: the largest y
    assert px[4, 2] == 0 and px[4, 0] == 254  # the bottom row is the smallest y
    assert (px[:, 3] == 205).all()  # unknown
    assert set(np.unique(px)) == {0, 205, 254}


def test_round_trip_export_import(tmp_path: Path) -> None:
    g = _grid()
    export_map_server(g, tmp_path / "m.yaml")
    back = import_map_server(tmp_path / "m.yaml")
    assert back.origin == pytest.approx(g.origin) and back.resolution == pytest.approx(0.1)
    assert np.array_equal(back.occupied, g.occupied)
    assert np.array_equal(back.free, g.free)
    assert np.array_equal(back.unknown, g.unknown)
    assert back.kind == "imported"


def test_import_reads_negate_and_thresholds_and_rejects_what_it_cannot(tmp_path: Path) -> None:
    Image.fromarray(np.array([[255, 100], [0, 180]], np.uint8)).save(tmp_path / "n.png")
    (tmp_path / "n.yaml").write_text(
        "image: n.png\nresolution: 0.5\norigin: [0, 0, 0]\nnegate: 1\noccupied_thresh: 0.6\nfree_thresh: 0.2\n"
    )
    g = import_map_server(tmp_path / "n.yaml")
    # negate 1: p = v / 255; image row 0 is the top (grid row 1)
    assert g.occupied[1, 0] and g.free[0, 0] and g.unknown[1, 1] and g.occupied[0, 1]
    (tmp_path / "r.yaml").write_text("image: n.png\nresolution: 0.5\norigin: [0, 0, 0.3]\n")
    with pytest.raises(InputError, match="yaw 0.3 is not supported"):
        import_map_server(tmp_path / "r.yaml")
    (tmp_path / "x.yaml").write_text("image: nothere.pgm\nresolution: 0.5\norigin: [0, 0, 0]\n")
    with pytest.raises(InputError, match="nothere.pgm not found"):
        import_map_server(tmp_path / "x.yaml")
    (tmp_path / "b.yaml").write_text("image: n.png\nresolution: fast\norigin: [0, 0, 0]\n")
    with pytest.raises(InputError, match="'resolution': not a number"):
        import_map_server(tmp_path / "b.yaml")
    (tmp_path / "raw.yaml").write_text("image: n.png\nmode: raw\nresolution: 0.5\norigin: [0, 0, 0]\n")
    with pytest.raises(InputError, match="'mode'"):
        import_map_server(tmp_path / "raw.yaml")


@pytest.mark.parametrize("yaw", [0.0, 1.0, -2.5, math.pi])
def test_pose_stamped_round_trip(yaw: float) -> None:
    msg = pose_stamped(1.5, -2.0, yaw, stamp=1700000000.25)
    assert msg["header"] == {"stamp": {"sec": 1700000000, "nanosec": 250000000}, "frame_id": "map"}
    json.dumps(msg)  # plain JSON
    x, y, back, frame = read_pose_stamped(msg)
    assert (x, y, frame) == (1.5, -2.0, "map")
    assert math.isclose(math.cos(back), math.cos(yaw), abs_tol=1e-9) and math.isclose(
        math.sin(back), math.sin(yaw), abs_tol=1e-9
    )
    with pytest.raises(InputError, match="PoseStamped"):
        read_pose_stamped({"pose": {}})


def test_map_command_exports_and_imports(tmp_path: Path, color_embedder) -> None:
    import ravenmem

    g = _grid()
    export_map_server(g, tmp_path / "given.yaml")
    ravenmem.create(tmp_path / "m.mem", embedder=color_embedder, ocr=False).close()
    rm = run_cli

    # the memory's embedder is a test class: importing a map never needs it
    r = rm(
        "map", "--memory", str(tmp_path / "m.mem"), "--import-nav2", str(tmp_path / "given.yaml"), "--json"
    )
    assert r.returncode == 0, r.stderr
    out = json.loads(r.stdout)
    assert out["kind"] == "imported" and out["occupied"] == 2 and out["unknown"] == 5 and out["free"] == 13
    r = rm("map", "--memory", str(tmp_path / "m.mem"), "--import-nav2", str(tmp_path / "given.yaml"))
    assert r.returncode == 2 and "--overwrite" in r.stderr
    r = rm("map", "--memory", str(tmp_path / "m.mem"), "--nav2", str(tmp_path / "again.yaml"), "--json")
    assert r.returncode == 0, r.stderr
    assert (tmp_path / "again.pgm").read_bytes() == (tmp_path / "given.pgm").read_bytes()
