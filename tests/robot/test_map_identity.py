"""Frames and map identity (REP 105) through the real command: `ingest` records the frame the
poses are in (odom for odometry, the TF parent otherwise) and a map identity (named with
--map-id, else derived from the recording); `info` shows both; a recording named to be in another
map, or with poses of another frame, is refused with one line naming both, nothing stored. The
bag's pose options have the link's names (--tf-parent, --tf-child, --time-source, --pose-match)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from tests.agent.conftest import color_plugin, forked_plugin_cli  # noqa: F401
from tests.cli.helpers import assert_one_line_error
from tests.ingest.bags import write_bag

IMAGES = "/camera/image_raw"


@pytest.fixture
def cli(forked_plugin_cli):  # noqa: F811
    """`ravenmem` with the colour embedder's plugin site, each command forked by one driver."""
    return forked_plugin_cli


def test_ingest_records_frame_and_map_and_refuses_another(cli, tmp_path: Path) -> None:
    bag = write_bag(tmp_path / "run1", "mcap", only={IMAGES, "/odom", "/tf", "/tf_static"})
    common = ["--embedder", "test-color", "--no-ocr", "--keyframes", "all", "--image-topic", IMAGES, "--json"]
    a = tmp_path / "a.mem"
    r = cli("ingest", str(bag), "-m", str(a), "--pose-topic", "/odom", *common)
    assert r.returncode == 0, r.stderr
    kept = json.loads(r.stdout)["kept"]
    info = json.loads(cli("info", "-m", str(a), "--json").stdout)
    assert info["frame_id"] == "odom"  # the odometry's header.frame_id: no map frame
    assert info["map_id"].startswith("rosbag:run1") and info["map_id"].endswith("#odom")
    assert info["anchor"] is None

    # the same bag posed through /tf into `map`: another frame, refused, nothing stored
    r = cli("ingest", str(bag), "-m", str(a), "--pose-topic", "/tf", "--tf-parent", "map", *common)
    assert "frame 'map'" in assert_one_line_error(r) and "'odom'" in r.stderr
    # a recording named to be in another map: refused, both maps named
    r = cli("ingest", str(bag), "-m", str(a), "--pose-topic", "/odom", "--map-id", "warehouse", *common)
    msg = assert_one_line_error(r)
    assert "'warehouse'" in msg and repr(info["map_id"]) in msg and "ravenmem align" in msg
    assert json.loads(cli("info", "-m", str(a), "--json").stdout)["memories"] == kept

    # a memory named at its first ingest, in map frame
    b = tmp_path / "b.mem"
    r = cli(
        "ingest",
        str(bag),
        "-m",
        str(b),
        "--pose-topic",
        "/tf",
        "--tf-parent",
        "map",
        "--map-id",
        "lab",
        *common,
    )
    assert r.returncode == 0, r.stderr
    info = json.loads(cli("info", "-m", str(b), "--json").stdout)
    assert (info["frame_id"], info["map_id"]) == ("map", "lab")
    shown = cli("info", "-m", str(b)).stdout
    assert "lab (poses in frame map)" in shown


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--time-source", "bag"], "time_source must be 'header' or 'receive'"),
        (["--pose-match", "closest"], "unknown pose matching 'closest'"),
        (["--map-id", " spaced "], "map id ' spaced '"),
    ],
)
def test_bad_pose_options_are_one_line_errors(cli, tmp_path: Path, args: list[str], message: str) -> None:
    bag = write_bag(tmp_path / "run", "mcap", only={IMAGES, "/odom"})
    r = cli("ingest", str(bag), "-m", str(tmp_path / "m.mem"), "--embedder", "test-color", "--no-ocr", *args)
    assert message in assert_one_line_error(r)
    assert not (tmp_path / "m.mem").exists()  # nothing was left behind
