"""`ravenmem ask --navigate`: the answer, then an A* path on the memory's own map from the
robot's last pose to the answer's position and heading; the real command in a subprocess, the
offline reasoner or a scripted VLM over HTTP."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from ravenmem.nav.goals import read_pose_stamped
from ravenmem.nav.grid import MapConfig, OccupancyGrid
from tests.agent.conftest import SCENE, run_cli
from tests.agent.scripted_server import answer, tool
from tests.agent.test_cli import ids_of

WALL_X = 9.5  # a wall between the robot's last pose (11, 4) and the magenta box seen at (7, 3)


def with_map(mem_path: Path) -> Path:
    """Give the scene memory a map: free floor around its trajectory, a wall at x = 9.5 from
    y = -1.5 to 4.2 (the way round is above it), the trajectory of the scene's poses."""
    grid = OccupancyGrid(MapConfig(resolution=0.1, robot_radius=0.2))
    for x in np.arange(-1.0, 12.01, 0.5):
        for y in np.arange(-1.0, 5.51, 0.5):
            grid.mark_free_disc(float(x), float(y), 0.5, floor_z=0.0)
    for y in np.arange(-1.5, 4.2, 0.05):
        r, c = grid.world_to_cell(WALL_X, float(y))
        grid.logodds[r, c - 1 : c + 2] = grid.config.l_clamp
        grid.known[r, c - 1 : c + 2] = True
    grid.touch()
    grid.trajectory = np.array([(x, y) for _, x, y in SCENE], np.float32)
    grid.save(mem_path)
    return mem_path


@pytest.fixture
def cli(color_plugin, tmp_path):
    home = tmp_path / "home"
    return lambda *args, **kw: run_cli(*args, site=color_plugin, home=home, **kw)


def vlm(server) -> tuple[str, ...]:
    return ("--base-url", server.base_url, "--model", "scripted-vlm")


def test_offline_answer_is_planned_around_the_wall(cli, mem_path):
    mem = str(with_map(mem_path))
    r = cli("ask", "Where did I leave the magenta box?", "-m", mem, "--offline", "--navigate", "--json")
    assert r.returncode == 0, r.stderr
    data = json.loads(r.stdout)
    assert data["position"] == [7.0, 3.0, 0.5]
    nav = data["navigation"]
    assert nav["ok"] and nav["start"] == pytest.approx([11.0, 4.0])  # the end of the trajectory
    gx, gy, gyaw = nav["goal"]
    assert math.dist((gx, gy), (7.0, 3.0)) < 0.1
    # the evidence camera's heading (a z-up robot: its yaw, 0.1 rad per frame, frame 7)
    assert gyaw == pytest.approx(0.7, abs=1e-6)
    straight = math.dist((11.0, 4.0), (7.0, 3.0))
    assert nav["path_length_m"] > straight + 0.3  # it went round the wall
    assert all(abs(x - WALL_X) > 0.15 or y > 4.2 for x, y in nav["waypoints"])
    x, y, yaw, frame = read_pose_stamped(nav["pose_stamped"])
    assert (frame, (x, y), yaw) == ("map", pytest.approx((gx, gy)), pytest.approx(gyaw))

    r = cli(
        "ask", "Where did I leave the magenta box?", "-m", mem, "--offline", "--navigate", "--from", "0,0"
    )
    assert r.returncode == 0, r.stderr
    lines = r.stdout.splitlines()
    assert any(ln.startswith("navigate: A* path") and "from (0.00, 0.00)" in ln for ln in lines), r.stdout
    stamped = json.loads(lines[-1])  # the goal for Nav2, on the last line
    assert stamped["header"]["frame_id"] == "map"


def test_the_models_yaw_is_the_goal_heading_on_a_z_up_map(cli, mem_path, server):
    mem = with_map(mem_path)
    ids = ids_of(mem)
    server.push(
        tool("search_time", time="+70"),  # memories 7-9 are shown to the model
        answer(question_type="position", evidence=[ids[7]], answer="There.", yaw_deg=-90),
    )
    r = cli("ask", "Where is the magenta box?", "-m", str(mem), *vlm(server), "--navigate", "--json")
    assert r.returncode == 0, r.stdout[-3000:]
    data = json.loads(r.stdout)
    assert data["yaw_source"] == "model"
    nav = data["navigation"]
    assert nav["ok"] and nav["goal"][2] == pytest.approx(-math.pi / 2) and nav["notes"] == []


def test_an_answer_without_a_place_is_no_path_and_exit_1(cli, mem_path, server):
    mem = str(with_map(mem_path))
    server.push(answer(question_type="position", found=False, answer="I did not see one."))
    r = cli("ask", "Where is the purple elephant?", "-m", mem, *vlm(server), "--navigate")
    assert r.returncode == 1, r.stderr
    assert "navigate: no path (answer): the answer has no position to go to (not found)" in r.stdout
    assert "Traceback" not in r.stderr


def test_navigate_needs_a_map_and_says_so_before_asking_the_model(cli, mem_path, server):
    r = cli("ask", "Where is the magenta box?", "-m", str(mem_path), *vlm(server), "--navigate")
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1 and "no map.npz" in r.stderr
    assert server.requests == []  # no model call was paid for a plan that could not be made


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (("--from", "1,2"), "--from and --robot-radius apply with --navigate only"),
        (("--navigate", "--from", "1"), "--from: expected 'x,y'"),
        (("--navigate", "--from", "nan,1"), "--from: x,y: nan is not a finite number"),
        (("--navigate", "--robot-radius", "-1"), "--robot-radius: expected metres from 0 to 10"),
        (("--max-position-offset", "-1"), "--max-position-offset: expected metres from 0 to"),
    ],
)
def test_bad_navigate_flags_are_one_line_errors(cli, mem_path, args, message):
    mem = str(with_map(mem_path))
    r = cli("ask", "Where is the magenta box?", "-m", mem, "--offline", *args)
    assert r.returncode == 2 and r.stdout == "", r.stdout
    assert len(r.stderr.strip().splitlines()) == 1 and message in r.stderr, r.stderr


def test_navigate_is_refused_with_a_server(cli):
    r = cli("ask", "Where is the magenta box?", "--server", "http://127.0.0.1:9", "--navigate")
    message = "--navigate plans on a local memory's map"
    assert r.returncode == 2 and r.stdout == "", r.stdout
    assert len(r.stderr.strip().splitlines()) == 1 and message in r.stderr, r.stderr
