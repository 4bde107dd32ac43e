"""The core commands end to end, as a user runs them (subprocess: real exit codes and output)."""

from __future__ import annotations

import json
from functools import partial
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from tests.cli.helpers import run_cli

REPO = Path(__file__).resolve().parents[2]


rm = partial(run_cli, timeout=600)


@pytest.fixture(scope="module")
def desk(tum_desk) -> Path:
    """The session's TUM memory (tests/conftest.py), built by `ravenmem ingest --stride 30 --json`."""
    out = tum_desk.report
    assert out["frames_seen"] == 723 and out["kept"] == 24 == out["memories_total"]
    return tum_desk.path


def test_search_modes_json(desk: Path, tmp_path: Path):
    r = rm("search", "a computer keyboard", "--memory", str(desk), "-k", "5", "--json")
    assert r.returncode == 0, r.stderr
    res = json.loads(r.stdout)["results"]
    assert len(res) == 5 and all(-1 <= x["score"] <= 1 for x in res)
    assert [x["score"] for x in res] == sorted((x["score"] for x in res), reverse=True)
    assert Path(res[0]["image"]).exists()

    r = rm("search", "--time", "00:00:12", "-k", "4", "--memory", str(desk), "--json")
    times = [x["offset_s"] for x in json.loads(r.stdout)["results"]]
    assert len(times) == 4 and times == sorted(times) and 11.5 <= times[0] <= 13.5

    r = rm("search", "--position", "1.3,0.6,1.6", "-k", "3", "--memory", str(desk), "--json")
    d = [x["distance"] for x in json.loads(r.stdout)["results"]]
    assert d == sorted(d) and d[0] < 0.1

    img = np.asarray(Image.open(res[0]["image"]))
    Image.fromarray(img).save(tmp_path / "q.png")
    r = rm("search", "--image", str(tmp_path / "q.png"), "--memory", str(desk), "-k", "1", "--json")
    top = json.loads(r.stdout)["results"][0]
    assert top["id"] == res[0]["id"] and top["score"] > 0.9  # a 320 px JPEG of the frame


def test_table_output_and_info(desk: Path):
    r = rm("search", "a monitor", "--memory", str(desk), "-k", "3")
    assert r.returncode == 0 and "text search: 3 result(s)" in r.stdout and "rank" in r.stdout
    r = rm("info", "--memory", str(desk), "--json")
    info = json.loads(r.stdout)
    assert info["memories"] == 24 and info["frames_seen"] == 723
    assert info["keyframe_ratio"] == pytest.approx(723 / 24)
    assert info["compression_vs_raw"] > 100 and info["bytes_per_memory"] > 0  # per-memory size: benchmarks/


@pytest.mark.parametrize(
    "args,msg",
    [
        (["search", "x", "--memory", "/nonexistent/m.mem"], "does not exist"),
        (["ingest", "/nonexistent/video.mp4", "--memory", "/tmp/never.mem"], "/nonexistent/video.mp4"),
        (["search", "--memory", "DESK"], "exactly one of"),
        (["search", "--position", "1,x", "--memory", "DESK"], "--position"),
        (["search", "--time", "next tuesday-ish", "--memory", "DESK"], "cannot read a time"),
    ],
)
def test_bad_input_one_clear_line(desk: Path, args: list[str], msg: str):
    args = [str(desk) if a == "DESK" else a for a in args]
    r = rm(*args)
    assert r.returncode == 2
    assert msg in r.stderr and "Traceback" not in r.stderr
    assert not Path("/tmp/never.mem").exists()
