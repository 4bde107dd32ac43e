"""`ravenmem view`: the .rrd written by the real command, read back with rerun's own reader."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from tests.cli.helpers import assert_one_line_error

from .helpers import T0, cli, cli_json, make_memory

rerun_chunk: Any = pytest.importorskip("rerun.chunk", reason="the view extra (rerun-sdk) is not installed")


@pytest.fixture(scope="module")
def memory(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return make_memory(tmp_path_factory.mktemp("view") / "robot.mem")


def read_rrd(path: Path) -> dict[tuple[str, bool], dict[str, list[Any]]]:
    """{(entity, static): {column: values}} of the file's one recording, chunks joined."""
    reader = rerun_chunk.RrdReader(path)
    assert [s.application_id for s in reader.recordings()] == ["ravenmem"]
    out: dict[tuple[str, bool], dict[str, list[Any]]] = {}
    for chunk in reader.stream().to_chunks():
        cols = out.setdefault((chunk.entity_path, chunk.is_static), {})
        batch = chunk.to_record_batch()
        for name in batch.schema.names:
            cols.setdefault(name, []).extend(batch.column(name).to_pylist())
    return out


def test_view_writes_trajectory_keyframes_and_hits(memory: Path, tmp_path: Path) -> None:
    out = tmp_path / "run.rrd"
    summary = cli_json(
        "view", "--memory", str(memory), "--out", str(out), "--query", "blue things", "-k", "3"
    )
    hits = cli_json("search", "blue things", "--memory", str(memory), "-k", "3")["results"]
    assert (
        summary["out"] == str(out)
        and summary["memories"] == 7
        and summary["images"] == 7
        and summary["hits"] == 3
    )
    assert out.read_bytes()[:4] == b"RRF2"  # rerun's file magic
    rrd = read_rrd(out)
    entities = {e for e, _ in rrd}
    assert {
        "/world/trajectory",
        "/world/memories",
        "/world/camera",
        "/world/camera/image",
        "/world/hits",
    } <= entities
    assert {"/query", "/hits/01", "/hits/02", "/hits/03"} <= entities and "/hits/04" not in entities

    # the trajectory: memory i at (i, 0.5 i, 0.1), in time order
    want = [[float(i), 0.5 * i, 0.1] for i in range(7)]
    assert np.allclose(rrd[("/world/trajectory", True)]["LineStrips3D:strips"][0], want)
    # every keyframe on the timeline with its pose (translation + yaw as a quaternion)
    cam = rrd[("/world/camera", False)]
    order = np.argsort(cam["memory"])
    assert [cam["memory"][i] for i in order] == list(range(1, 8))
    times = [cam["time"][i].timestamp() for i in order]
    assert times == pytest.approx([T0 + 10 * i for i in range(7)])
    assert np.allclose([cam["Transform3D:translation"][i][0] for i in order], want)
    quats = np.asarray([cam["Transform3D:quaternion"][i][0] for i in order])
    assert np.allclose(quats, [[0, 0, math.sin(0.1 * i), math.cos(0.1 * i)] for i in range(7)], atol=1e-6)
    # the thumbnails as stored, byte for byte
    imgs = rrd[("/world/camera/image", False)]
    blobs = dict(zip(imgs["memory"], imgs["EncodedImage:blob"], strict=True))
    thumbs = sorted((memory / "thumbs").glob("*.jpg"))  # named by time, so in memory order
    assert [bytes(blobs[i + 1][0]) for i in range(7)] == [p.read_bytes() for p in thumbs]
    # the query's hits, where the search puts them, labelled with rank and score
    marked = rrd[("/world/hits", True)]
    assert np.allclose(marked["Points3D:positions"][0], [[h["x"], h["y"], h["z"]] for h in hits])
    assert marked["Points3D:labels"][0] == [f"#{h['rank']} {h['score']:.2f}" for h in hits]
    doc = rrd[("/query", True)]["TextDocument:text"][0][0]
    assert doc.startswith("# blue things") and all(f"| {h['id']} |" in doc for h in hits)


def test_view_defaults_next_to_the_memory_and_limits_pictures(memory: Path) -> None:
    out = memory.with_suffix(".rrd")
    try:
        summary = cli_json("view", "--memory", str(memory), "--max-images", "3")
        assert summary["out"] == str(out) and summary["images"] == 3 and summary["hits"] == 0
        rrd = read_rrd(out)
        assert len(rrd[("/world/camera", False)]["memory"]) == 7  # every pose
        assert sorted(rrd[("/world/camera/image", False)]["memory"]) == [1, 4, 7]  # every 3rd picture
        assert not any(e.startswith("/hits") or e == "/world/hits" for e, _ in rrd)
    finally:
        out.unlink(missing_ok=True)


def test_view_bad_input(memory: Path, tmp_path: Path) -> None:
    r = cli("view", "--memory", str(memory), "--out", str(tmp_path / "x.rrd"), "--camera-axes", "up")
    assert "camera axes" in assert_one_line_error(r)
    r = cli("view", "--memory", str(tmp_path / "missing"), "--out", str(tmp_path / "x.rrd"))
    assert_one_line_error(r)
    blocker = tmp_path / "file"
    blocker.write_text("x")
    r = cli("view", "--memory", str(memory), "--out", str(blocker / "x.rrd"))
    assert "--out: the folder" in assert_one_line_error(r)  # refused before anything is drawn
    assert not (tmp_path / "x.rrd").exists()
