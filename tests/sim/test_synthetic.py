import math

import numpy as np
import pytest

import ravenmem
from ravenmem.nav import OccupancyGrid
from ravenmem.robot.explore import ExploreConfig, Explorer
from ravenmem.robot.mission import coverage_reference, explore_into, load_exploration, navigate_to
from ravenmem.sim import Environment, create_env
from ravenmem.sim.control import follow_waypoints
from ravenmem.sim.synthetic import SyntheticEnv


def _seg_dist(p: np.ndarray, segs: np.ndarray) -> np.ndarray:
    x1, y1, x2, y2 = segs.T
    ex, ey = x2 - x1, y2 - y1
    t = np.clip(((p[:, :1] - x1) * ex + (p[:, 1:] - y1) * ey) / np.maximum(ex * ex + ey * ey, 1e-12), 0, 1)
    return np.hypot(p[:, :1] - (x1 + t * ex), p[:, 1:] - (y1 + t * ey)).min(axis=1)


def test_protocol_and_depth_geometry() -> None:
    env = create_env("synthetic:rooms", start_time=100.0)
    assert isinstance(env, Environment)
    obs = env.reset()
    assert obs.rgb.shape == (120, 160, 3) and obs.rgb.dtype == np.uint8 and obs.t == 100.0
    # Face the east wall of the first room's doorway wall (x = 8) from (2, 3): 6 m straight ahead.
    assert isinstance(env, SyntheticEnv)
    _, depth, _ = env.render(2.0, 1.0, 0.0)
    assert depth[60 - 5, 80] == pytest.approx(6.0, abs=1e-6)  # just above the horizon row
    assert depth[-1, 80] == pytest.approx(0.8 / ((119.5 - 60) / 80), rel=1e-6)  # floor below the camera
    with pytest.raises(Exception, match="unknown world"):
        create_env("synthetic:nowhere")


def test_controller_reaches_waypoints_and_reports_bumps() -> None:
    env = create_env("synthetic:rooms", start_time=0.0)
    obs = env.reset()
    res = follow_waypoints(env, [(obs.pose.x, obs.pose.y), (4.0, 1.5), (4.0, 4.0)], max_steps=300, start=obs)
    assert res.reached and math.dist((res.last.pose.x, res.last.pose.y), (4.0, 4.0)) <= 0.35
    assert res.distance_m == pytest.approx(2.0 + 2.5, rel=0.25)
    res = follow_waypoints(env, [(4.0, 9.0)], max_steps=300, start=res.last)  # through the north wall
    assert not res.reached and res.reason == "stuck"


def test_exploration_covers_the_rooms_and_maps_the_walls(tmp_path, box_embedder) -> None:
    env = create_env("synthetic:rooms", start_time=1.7e9)
    mem = ravenmem.create(tmp_path / "rooms.mem", embedder=box_embedder, ocr=False)
    grid, rep = explore_into(env, mem, ExploreConfig(steps=700, resolution=0.2, keyframe_dist=1.0))
    assert rep.stop_reason == "no reachable frontier left"
    assert rep.coverage[-1][3] > 0.9
    # coverage grows over time (cells may flip to occupied, so allow a small dip)
    fracs = [c[3] for c in rep.coverage]
    assert fracs[0] < 0.5 and all(b >= a - 0.02 for a, b in zip(fracs, fracs[1:]))
    assert rep.seen_objects == {0, 1, 2}
    assert mem.count() == len(rep.keyframes) > 10
    # mapped obstacles lie on true walls or box sides
    rr, cc = np.nonzero(grid.occupied)
    centres = np.stack([grid.origin[0] + (cc + 0.5) * 0.2, grid.origin[1] + (rr + 0.5) * 0.2], 1)
    near = _seg_dist(centres, env.wall_segments()) <= 0.3
    assert near.mean() > 0.95
    # saved with the memory and reloadable
    back = OccupancyGrid.load(mem.path)
    assert np.array_equal(back.occupied, grid.occupied)
    assert load_exploration(mem.path)["env"] == "synthetic:rooms"
    # Phase II: the memory finds the red box; A* drives there without exploring
    hit = mem.search_text("the red box", k=1)[0].memory
    nav = navigate_to(env, back, (hit.pose.x, hit.pose.y), max_steps=600)
    assert nav.reached and nav.plan is not None and nav.plan.ok
    assert math.dist((nav.last.pose.x, nav.last.pose.y), (3.0, 4.5)) < 3.0
    mem.close()


def test_unreachable_goal_does_not_move_the_robot() -> None:
    env = create_env("synthetic:rooms", start_time=0.0)
    env.reset()
    ex = Explorer(env, None, ExploreConfig(steps=150, resolution=0.2))
    ex.run(reset=False)
    before = env.observe().pose
    nav = navigate_to(env, ex.grid, (40.0, 40.0), max_steps=100)
    assert not nav.reached and "unreachable" in nav.reason and nav.steps == 0
    assert env.observe().pose == before


def test_coverage_reference_counts_only_reachable_floor() -> None:
    env = create_env("synthetic:rooms", start_time=0.0)
    env.reset()
    ref = coverage_reference(env, 0.25)
    assert ref is not None
    assert ref(OccupancyGrid()) == 0.0


def test_bad_explore_config_is_one_clear_error() -> None:
    from ravenmem.errors import InputError

    with pytest.raises(InputError, match="steps"):
        ExploreConfig(steps=0)
    with pytest.raises(InputError, match="resolution"):
        ExploreConfig(resolution=-1.0)
