"""A short ViZDoom episode (well under a minute): metric depth, mapping and planning on Freedoom."""

import math

import numpy as np
import pytest

pytest.importorskip("vizdoom")

from ravenmem.errors import InputError  # noqa: E402
from ravenmem.nav import plan_path  # noqa: E402
from ravenmem.robot.explore import ExploreConfig, Explorer  # noqa: E402
from ravenmem.sim import create_env  # noqa: E402
from ravenmem.sim.control import follow_waypoints  # noqa: E402
from ravenmem.sim.groundtruth import reachable_floor  # noqa: E402


def _seg_dist(p: np.ndarray, segs: np.ndarray) -> np.ndarray:
    x1, y1, x2, y2 = segs.T
    ex, ey = x2 - x1, y2 - y1
    t = np.clip(((p[:, :1] - x1) * ex + (p[:, 1:] - y1) * ey) / np.maximum(ex * ex + ey * ey, 1e-12), 0, 1)
    return np.hypot(p[:, :1] - (x1 + t * ex), p[:, 1:] - (y1 + t * ey)).min(axis=1)


@pytest.fixture(scope="module")
def env():
    e = create_env("vizdoom:freedoom2/MAP02", start_time=1.7e9)
    yield e
    e.close()


def test_bad_specs_are_clear() -> None:
    with pytest.raises(InputError, match="not found"):
        create_env("vizdoom:/nowhere/x.wad/MAP01")
    with pytest.raises(InputError, match="no map MAP99"):
        create_env("vizdoom:freedoom2/MAP99")
    with pytest.raises(InputError, match="resolution"):
        create_env("vizdoom:freedoom2/MAP01", width=123, height=45)


def test_observation_pose_objects_and_metric_depth(env) -> None:
    obs = env.reset()
    assert obs.rgb.shape == (240, 320, 3) and obs.depth.shape == (240, 320)
    assert env.intrinsics.fx == pytest.approx(160.0) and env.intrinsics.fy == pytest.approx(184.0)
    assert obs.pose.x == pytest.approx(20.0) and obs.pose.y == pytest.approx(-18.0)  # Doom (640, -576) / 32
    assert obs.pose.z == pytest.approx(41 / 32, abs=0.01) and obs.floor_z == pytest.approx(0.0)
    assert obs.camera_height == pytest.approx(env.robot.camera_height, abs=0.01)
    kinds = {o.kind for o in env.objects()}
    assert {"GreenArmor", "Shotgun", "Medikit"} <= kinds and "DoomPlayer" not in kinds
    # Depth is metric: wall pixels near the horizon, projected with the pose, land on the map's lines.
    segs = env.wall_segments(solid_only=False)
    intr = env.intrinsics
    errs = []
    for _ in range(6):
        obs = env.step(0.0, math.radians(60))
        v, u = np.mgrid[100:140:6, 0:320:9]
        d = obs.depth[v, u].astype(float)
        ok = d > 0
        xr = (u[ok] + 0.5 - intr.cx) / intr.fx * d[ok]
        c, s = math.cos(obs.pose.yaw), math.sin(obs.pose.yaw)
        pts = np.stack([obs.pose.x + d[ok] * c + xr * s, obs.pose.y + d[ok] * s - xr * c], 1)
        errs.append(_seg_dist(pts, segs))
    err = np.concatenate(errs)
    assert err.size > 200 and np.median(err) < 0.1 and np.mean(err < 0.3) > 0.9


def test_short_episode_maps_and_plans(env) -> None:
    obs = env.reset()
    truth = reachable_floor(env.wall_segments(), (obs.pose.x, obs.pose.y), 0.25)
    ex = Explorer(env, None, ExploreConfig(steps=400), coverage_ref=truth.coverage)
    rep = ex.run(reset=False)
    grid = ex.grid
    assert rep.steps >= 390 and rep.distance_m > 10.0
    assert rep.coverage[-1][3] > 0.1 and rep.coverage[-1][2] > 150.0
    # mapped obstacles are real: most lie within 0.5 m of a wall line or a solid object
    rr, cc = np.nonzero(grid.occupied)
    centres = np.stack(
        [grid.origin[0] + (cc + 0.5) * grid.resolution, grid.origin[1] + (rr + 0.5) * grid.resolution], 1
    )
    near_wall = _seg_dist(centres, env.wall_segments(solid_only=False)) <= 0.5
    objs = np.array([(o.x, o.y) for o in env.objects()])
    near_obj = np.min(np.hypot(centres[:, :1] - objs[:, 0], centres[:, 1:] - objs[:, 1]), axis=1) <= 0.6
    assert rr.size > 200 and np.mean(near_wall | near_obj) > 0.85
    # plan back to the start over the map and drive it
    here = env.observe()
    plan = plan_path(grid, (here.pose.x, here.pose.y), (20.0, -18.0), env.robot.radius)
    assert plan.ok and plan.length_m >= math.dist((here.pose.x, here.pose.y), (20.0, -18.0)) - 0.5
    res = follow_waypoints(env, plan.waypoints, max_steps=600, start=here)
    assert res.reached, res.reason
    assert math.dist((res.last.pose.x, res.last.pose.y), (20.0, -18.0)) < 0.5


def test_the_simulator_writes_nothing_into_the_working_folder(tmp_path, monkeypatch) -> None:
    monkeypatch.chdir(tmp_path)
    e = create_env("vizdoom:freedoom2/MAP01")
    e.reset()
    e.close()
    assert list(tmp_path.iterdir()) == []


def test_keyframe_labels_place_objects_where_they_are(env) -> None:
    from ravenmem.robot.explore import locate

    obs = env.reset()
    truth = {o.id: o for o in env.objects()}
    errs = []
    for _ in range(12):  # look around from the start
        obs = env.step(0.0, math.radians(30))
        for oid, box in obs.visible_boxes.items():
            xy = locate(obs, box, env.intrinsics)
            if xy is not None:
                errs.append(
                    math.dist(xy, (truth[oid].x, truth[oid].y))
                    / max(1.0, math.dist(xy, (obs.pose.x, obs.pose.y)))
                )
    assert len(errs) >= 5 and np.median(errs) < 0.15  # within 15 % of the distance


def test_a_picture_of_an_object_from_elsewhere(env, tmp_path) -> None:
    from ravenmem.robot.explore import ExploreConfig, Explorer
    from ravenmem.robot.pictures import query_picture

    env.reset()
    ex = Explorer(env, None, ExploreConfig(steps=200))
    rep = ex.run(reset=False)
    kf = np.asarray(rep.trajectory[::20])
    pictured = 0
    for obj in sorted((o for o in env.objects() if o.id in rep.seen_objects), key=lambda o: o.id)[:4]:
        pic = query_picture(env, ex.grid, obj, kf, env.robot.radius)
        if pic is None:
            continue
        pictured += 1
        assert pic.shape == (240, 320, 3) and pic.dtype == np.uint8
        here = env.observe()
        assert min(math.dist((here.pose.x, here.pose.y), p) for p in kf) >= 0.9  # not a stored view
        assert obj.id in here.visible_boxes  # the object is in the picture
    assert pictured >= 2
