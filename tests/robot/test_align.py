"""`ravenmem align`: two explorations of one simulated world whose starts differ by a known
offset (the second robot reports its poses from its own start, frame `odom`). The real command
estimates the offset from the places both saw (image matches, RANSAC on the poses, then the
maps fitted), re-anchors the first memory into the second's map with --apply, and an object
remembered in the first session is driven to in the second session's world with the second
session's map; --undo puts everything back; a killed re-anchoring is finished by the next writer."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

import ravenmem
from ravenmem.agent.methods import create_method
from ravenmem.memory.anchor import Transform
from ravenmem.nav.goals import goal_for
from ravenmem.nav.grid import OccupancyGrid
from ravenmem.robot.explore import ExploreConfig
from ravenmem.robot.mission import explore_into, navigate_to
from ravenmem.sim.synthetic import SyntheticEnv
from tests.cli.helpers import assert_one_line_error, run_cli
from tests.robot import sessions as S

REPO = Path(__file__).resolve().parents[2]
BLUE = (12.5, -1.5)  # the blue box, world frame
BLUE_ID = 1  # its id in `sessions.lab_world`


def sees_blue(x: float, y: float, yaw: float) -> bool:
    """Whether a camera at this world pose has the blue box in view."""
    _, _, boxes = SyntheticEnv(S.lab_world()).render(x, y, yaw)
    return BLUE_ID in boxes


@pytest.fixture(scope="module")
def tiny_plugin(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A folder that, on PYTHONPATH, registers `test-tiny` by entry point for the real command."""
    site = tmp_path_factory.mktemp("site")
    (site / "ravenmem_test_tiny.py").write_text(
        "from tests.robot.sessions import TinyImageEmbedder\n\ndef make(spec, **kw):\n    return TinyImageEmbedder()\n"
    )
    dist = site / "ravenmem_test_tiny-0.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: ravenmem-test-tiny\nVersion: 0\n")
    (dist / "entry_points.txt").write_text("[ravenmem.embedders]\ntest-tiny = ravenmem_test_tiny:make\n")
    return site


def rm(site: Path, *args: str) -> subprocess.CompletedProcess[str]:
    return run_cli(*args, paths=(site,))


def explore(path: Path, env: object, map_id: str, frame_id: str) -> None:
    mem = ravenmem.create(path, embedder=S.TinyImageEmbedder(), ocr=False, thumb_size=64)
    mem.claim_map(map_id, frame_id)
    explore_into(env, mem, ExploreConfig(steps=1200, keyframe_dist=0.3, keyframe_turn=math.radians(10)))  # type: ignore[arg-type]
    mem.close()


@pytest.fixture(scope="module")
def sessions(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[Path, Path]]:
    d = tmp_path_factory.mktemp("sessions")
    explore(d / "first.mem", SyntheticEnv(S.lab_world(), start_time=S.T0), "lab, first session", "map")
    explore(d / "second.mem", S.OdomEnv(S.SECOND_START, S.T0 + 86400), "lab, second session", "odom")
    yield d / "first.mem", d / "second.mem"


def where_is_blue(mem: ravenmem.Memory) -> object:
    """Ask a memory where it saw the blue box, by a picture of it (taken in the world)."""
    pic, _, boxes = SyntheticEnv(S.lab_world()).render(12.5, 0.2, -math.pi / 2)
    assert boxes, "the query picture shows the box"
    ans = create_method("embedder-only", mem).ask("where did I see this?", image=pic)
    ans.frame_id, ans.map_id = mem.frame_id, mem.map_id
    return ans


def test_align_recovers_the_offset_and_the_second_session_drives_to_the_first_ones_object(
    sessions: tuple[Path, Path], tiny_plugin: Path
) -> None:
    first, second = sessions
    truth = S.true_offset()
    with ravenmem.open(first) as a, ravenmem.open(second) as b:
        before = {r.id: r.pose for r in a.all_records()}
        answer = where_is_blue(a)
        assert sees_blue(answer.position[0], answer.position[1], answer.yaw)  # world frame: session 1's
        gp = goal_for(answer, b)
        assert not gp.ok and gp.problem == "map"  # no transform known between the two maps yet
        assert "'lab, first session'" in gp.reason and "'lab, second session'" in gp.reason

    r = rm(tiny_plugin, "align", "--from", str(first), "--to", str(second), "--json")
    assert r.returncode == 0, r.stderr
    est = json.loads(r.stdout)
    t = est["transform"]
    assert math.hypot(t["x"] - truth.x, t["y"] - truth.y) < 0.2, est
    assert S.yaw_error_deg(t["yaw"], truth.yaw) < 2.0, est
    assert est["method"] == "images+maps" and est["inliers"] >= 4 and est["matches"] >= est["inliers"]
    with ravenmem.open(first) as a:  # estimating wrote nothing
        assert a.map_id == "lab, first session" and {r.id: r.pose for r in a.all_records()} == before

    r = rm(tiny_plugin, "align", "--from", str(first), "--to", str(second), "--apply")
    assert r.returncode == 0, r.stderr
    assert "now in map 'lab, second session'" in r.stdout
    with ravenmem.open(first) as a, ravenmem.open(second) as b:
        assert (a.map_id, a.frame_id) == ("lab, second session", "odom")
        assert a.info()["anchor"]["from"] == {"frame_id": "map", "map_id": "lab, first session"}
        moved = {r.id: r.pose for r in a.all_records()}
        for rid in list(before)[::20]:  # each pose went through the estimate, from the original
            want = Transform(t["x"], t["y"], t["z"], t["yaw"]).apply(before[rid])
            assert (moved[rid].x, moved[rid].y, moved[rid].yaw) == pytest.approx(
                (want.x, want.y, want.yaw), abs=1e-9
            )
        # the first session's map was moved with its poses: its walls lie on the second's
        grid_a, grid_b = OccupancyGrid.load(first), OccupancyGrid.load(second)
        rows, cols = np.nonzero(grid_a.occupied)
        pts = np.c_[
            grid_a.origin[0] + (cols + 0.5) * grid_a.resolution,
            grid_a.origin[1] + (rows + 0.5) * grid_a.resolution,
        ]
        on_b = [
            grid_b.occupied[grid_b.world_to_cell(x, y)] or _near_occupied(grid_b, x, y) for x, y in pts[::7]
        ]
        assert np.mean(on_b) > 0.8

        # the object of the first session, driven to in the second session's world and map
        answer = where_is_blue(a)
        gp = goal_for(answer, b)
        assert gp.ok, gp.reason
        assert gp.frame_id == "odom" and gp.pose_stamped()["header"]["frame_id"] == "odom"
        own = goal_for(answer, a)  # on the first memory's own (moved) map: about the same goal
        assert own.ok and math.dist(own.goal[:2], gp.goal[:2]) < 0.5
        env = S.OdomEnv(S.SECOND_START, S.T0 + 2 * 86400)
        nav = navigate_to(env, OccupancyGrid.load(second), gp.goal[:2], max_steps=1500, start=env.reset())
        assert nav.reached, nav.reason
        to_world = env.to_odom.inverse()
        world = to_world.apply(nav.last.pose)
        # where the first session saw the box, in the real world, and facing the goal's way it is in view
        assert math.dist((world.x, world.y), to_world.xy(*answer.position[:2])) < 0.6
        assert sees_blue(world.x, world.y, gp.goal[2] + to_world.yaw)

    # a later correction starts from the original poses, not from the last re-anchoring
    given = f"{t['x']},{t['y'] + 0.5},{t['z']},{math.degrees(t['yaw'])}"
    for _ in range(2):
        r = rm(
            tiny_plugin,
            "align",
            "--from",
            str(first),
            "--to",
            str(second),
            "--transform",
            given,
            "--apply",
            "--json",
        )
        assert r.returncode == 0, r.stderr
    with ravenmem.open(first) as a:
        rid = next(iter(before))
        want = Transform(t["x"], t["y"] + 0.5, t["z"], t["yaw"]).apply(before[rid])
        got = a.get([rid])[0].pose
        assert (got.x, got.y) == pytest.approx((want.x, want.y), abs=1e-6)

    r = rm(tiny_plugin, "align", "--from", str(first), "--undo", "--json")
    assert r.returncode == 0, r.stderr
    with ravenmem.open(first) as a, ravenmem.open(second) as b:
        assert a.map_id == "lab, first session" and a.frame_id == "map" and a.info()["anchor"] is None
        back = {r.id: r.pose for r in a.all_records()}
        for rid, p in before.items():
            assert (back[rid].x, back[rid].y, back[rid].yaw) == pytest.approx((p.x, p.y, p.yaw), abs=1e-9)
        assert not goal_for(where_is_blue(a), b).ok
        assert OccupancyGrid.load(first).meta.get("anchor") is None


def _near_occupied(grid: OccupancyGrid, x: float, y: float, r: float = 0.3) -> bool:
    for dx in (-r, 0.0, r):
        for dy in (-r, 0.0, r):
            c = grid.world_to_cell(x + dx, y + dy)
            if grid.contains(c) and grid.occupied[c]:
                return True
    return False


def test_align_refuses_what_it_cannot_do(
    sessions: tuple[Path, Path], tiny_plugin: Path, tmp_path: Path
) -> None:
    first, second = sessions
    other = tmp_path / "other.mem"
    ravenmem.create(other, embedder="offline", ocr=False).close()
    cases = [
        (["--from", str(first), "--to", str(first)], "the same memory"),
        (["--from", str(first), "--to", str(other)], "different embedders"),
        (["--from", str(first), "--to", str(second), "--transform", "1,2"], "--transform: expected 4"),
        (["--from", str(first), "--undo"], "never re-anchored"),
        (["--from", str(first)], "give --to"),
    ]
    for args, message in cases:
        assert message in assert_one_line_error(rm(tiny_plugin, "align", *args)), args


def _killed_reanchoring(path: Path) -> None:
    """A memory of five poses in map 'old' whose re-anchoring to 'new' (+10 m in x, a quarter
    turn) was killed after the store took the new poses, before the manifest named the new map."""
    from ravenmem.types import Frame, Pose
    from tests.conftest import ColorEmbedder, solid

    with ravenmem.create(path, embedder=ColorEmbedder(), ocr=False, thumb_size=0) as mem:
        mem.add_frames(
            [Frame(solid("red"), 100.0 + i, Pose(float(i), 0.0, 0.0, 0.1 * i), "s", i) for i in range(5)]
        )
        mem.claim_map("old", "map")
    script = (
        "import sys, os, math\n"
        "sys.path[:0] = [sys.argv[2], sys.argv[3]]\n"
        "import ravenmem\n"
        "from ravenmem.memory import manifest as mf\n"
        "from ravenmem.memory.anchor import Transform\n"
        "from tests.conftest import ColorEmbedder\n"
        "mem = ravenmem.open(sys.argv[1], embedder=ColorEmbedder(), writable=True)\n"
        "mf.Manifest.save = lambda self, folder: os._exit(9)\n"
        "mem.reanchor(Transform(10.0, 0.0, 0.0, math.pi / 2), 'new', 'map')\n"
    )
    r = subprocess.run(
        [sys.executable, "-c", script, str(path), str(REPO / "src"), str(REPO)],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert r.returncode == 9, r.stderr
    assert (path / "anchor" / "pending.json").is_file()


def test_a_killed_reanchoring_is_finished_by_the_next_writer(tmp_path: Path) -> None:
    """The next writer finds the journal and finishes from the original poses."""
    from tests.conftest import ColorEmbedder

    path = tmp_path / "m.mem"
    _killed_reanchoring(path)
    with ravenmem.open(path, embedder=ColorEmbedder()) as mem:  # a reader sees the moved poses
        assert mem.map_id == "old"  # not finished yet: the manifest was never written
    with ravenmem.open(path, embedder=ColorEmbedder(), writable=True) as mem:
        assert mem.map_id == "new" and not (path / "anchor" / "pending.json").exists()
        p = mem.get([3])[0].pose  # the third memory: (2, 0), turned 90 degrees, then +10 in x
        assert (p.x, p.y, p.yaw) == pytest.approx((10.0, 2.0, 0.2 + math.pi / 2))


def test_an_unreadable_reanchoring_journal_is_set_aside_and_the_poses_follow_the_manifest(
    tmp_path: Path,
) -> None:
    """A journal nobody can act on (damaged by hand or disk) does not wedge the memory: the next
    writer logs it, sets it aside, and puts back the poses the manifest names (the originals
    here: it was never re-anchored), undoing the half-applied move; a writer command works."""
    from tests.conftest import ColorEmbedder

    path = tmp_path / "m.mem"
    _killed_reanchoring(path)
    journal = path / "anchor" / "pending.json"
    journal.write_text('{"anchor": {"transform": "not four numbers"}', encoding="utf-8")
    with ravenmem.open(path, embedder=ColorEmbedder()) as mem:  # the half-applied move
        assert mem.get([3])[0].pose.x == pytest.approx(10.0)
    with ravenmem.open(path, embedder=ColorEmbedder(), writable=True) as mem:
        assert mem.map_id == "old"
        p = mem.get([3])[0].pose
        assert (p.x, p.y, p.yaw) == pytest.approx((2.0, 0.0, 0.2))
    assert not journal.exists() and (path / "anchor" / "pending.json.aside").is_file()
