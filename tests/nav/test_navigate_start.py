"""`ravenmem navigate` finds its start by itself: when the robot's last pose lies in a pocket the
map closes off, it plans from the nearest cell that reaches the goal and says so; a start the
user gives is never moved. The real command in a subprocess, on a small memory with a map."""

from __future__ import annotations

import json
import math
import re
from pathlib import Path

import numpy as np
import pytest

from ravenmem.nav.grid import MapConfig, OccupancyGrid
from tests.agent.conftest import SCENE, color_plugin, mem_path, run_cli  # noqa: F401

LAST = (11.0, 4.0)  # the scene's last pose: the end of the map's trajectory


def with_pocket(mem: Path) -> Path:
    """Free floor around the scene's poses, and a ring of wall 0.6 m around the last pose: the
    robot's last pose is in a pocket of about 1 m^2 that no path leaves."""
    grid = OccupancyGrid(MapConfig(resolution=0.1, robot_radius=0.2))
    for x in np.arange(-1.0, 12.51, 0.5):
        for y in np.arange(-1.0, 6.01, 0.5):
            grid.mark_free_disc(float(x), float(y), 0.5, floor_z=0.0)
    for a in np.linspace(0, 2 * math.pi, 400):
        r, c = grid.world_to_cell(LAST[0] + 0.6 * math.cos(a), LAST[1] + 0.6 * math.sin(a))
        grid.logodds[r, c] = grid.config.l_clamp
        grid.known[r, c] = True
    grid.touch()
    grid.trajectory = np.array([(x, y) for _, x, y in SCENE], np.float32)
    grid.save(mem)
    return mem


@pytest.fixture
def cli(color_plugin, tmp_path):  # noqa: F811
    return lambda *args: run_cli(*args, site=color_plugin, home=tmp_path / "home")


def test_a_cut_off_last_pose_gives_the_nearest_start_that_reaches_the_goal(cli, mem_path) -> None:  # noqa: F811
    mem = str(with_pocket(mem_path))
    r = cli("navigate", "-m", mem, "--to", "yellow box", "--json")
    assert r.returncode == 0, r.stdout + r.stderr
    plan = json.loads(r.stdout)
    sx, sy = plan["start"]
    moved = math.dist((sx, sy), LAST)
    assert plan["ok"] and 0.6 < moved < 1.2  # just outside the ring
    note = next(n for n in plan["notes"] if n.startswith("started "))
    assert f"started {moved:.2f} m from the robot's last pose (11.00, 4.00)" in note
    assert "is cut off from the goal" in note or "not in known free space" in note
    # in words, with rounded numbers: the answer, the start used, the note, the goal for Nav2
    r = cli("navigate", "-m", mem, "--to", "yellow box")
    assert r.returncode == 0, r.stderr
    lines = r.stdout.splitlines()
    assert lines[0].startswith("answer (offline): (2.00, 0.00") and "; A* path" in lines[0]
    assert f"from ({sx:.2f}, {sy:.2f})" in lines[0]
    assert any(ln.strip().startswith("note: started") for ln in lines)
    digits = [len(d) for d in re.findall(r"\.(\d+)", r.stdout)]
    assert digits and max(digits) <= 4, r.stdout  # no raw floats
    stamped = json.loads(lines[-1])
    assert stamped["header"]["frame_id"] == "map"


def test_a_start_the_user_gives_is_never_moved(cli, mem_path) -> None:  # noqa: F811
    mem = str(with_pocket(mem_path))
    r = cli("navigate", "-m", mem, "--to", "yellow box", "--from", "11,4", "--json")
    assert r.returncode == 1
    plan = json.loads(r.stdout)
    assert not plan["ok"] and plan["problem"] == "start" and plan["start"] == [11.0, 4.0]
    assert "give another start" in plan["reason"]
