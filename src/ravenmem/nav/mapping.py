"""Occupancy maps from recorded RGB-D: every depth frame with its pose, not only keyframes.

The steps, per depth frame (the paper's recipe, for a camera that may pitch and roll):

1. Back-project every `stride`-th pixel with the camera intrinsics, move the points into the
   world with the frame's pose and the camera mount (`extrinsic`: the optical frame, x right,
   y down, z forward, in the pose's frame).
2. Heights are measured from the floor plane (`MapFrame`), found from the data once per map:
   a first guess of "up" from the pose convention (the mean of the cameras' image-up
   directions: people and robots hold cameras roughly upright), then the lowest large
   horizontal plane below the cameras, refined by a least-squares plane fit (`fit_floor`).
3. Points between `step_height` and `obstacle_max` above the floor are obstacles (a cell needs
   `min_points` of them in one frame), points within `step_height` of the floor are floor,
   higher points pass over the robot and are ignored.
4. Ray casting on the map: from the camera's map position to every floor or obstacle cell,
   cells before the first obstacle of this frame are free; the obstacle cells are occupied.
   Log-odds accumulate over frames; unknown stays distinct from free.
5. The footprint under the camera is free (it was carried or driven there), and planning
   inflates obstacles by the robot radius (exact Euclidean distance, `OccupancyGrid.inflated`).

`MapBuilder` does this incrementally and saves the map in the memory folder (crash-safe), so
the ingest pipeline feeds it every posed depth frame, a second ingest extends the same map
(frames already in it are skipped by time), and a live robot can call `add` as it goes.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from ..errors import InputError
from ..memory.folder import MAP_GRID
from ..types import Frame, Intrinsics, Pose
from .frame import MapFrame
from .grid import MapConfig, OccupancyGrid

# The camera's optical frame (x right, y down, z forward) in two common pose frames.
OPTICAL = np.eye(4)  # the pose is the optical frame itself (TUM ground truth, ROS *_optical_frame)
BODY = np.eye(4)  # the pose is a body frame, x forward, y left, z up (ROS REP-103 base_link)
BODY[:3, :3] = [[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]]
MOUNTS = {"optical": OPTICAL, "body": BODY}

SKIP_DONE = "already in the map"
SKIP_NO_CAMERA = "no camera intrinsics"
SKIP_BAD_DEPTH = "depth image does not match the camera"
MIN_POINTS = 2  # obstacle points a cell needs in one frame, so single speckles do not become walls


def recording_config(resolution: float = 0.05, robot_radius: float = 0.25) -> MapConfig:
    """Defaults for maps from real RGB-D: 5 cm cells, a Kinect-class sensor's trusted range."""
    return MapConfig(
        resolution=resolution,
        step_height=0.1,
        obstacle_max=1.8,
        min_range=0.3,
        max_range=5.0,
        explore_range=5.0,
        stride=4,
        require_floor=False,
        robot_radius=robot_radius,
    )


def mount(spec: str | np.ndarray | None) -> np.ndarray:
    """A camera mount (4x4, optical frame in the pose frame) from 'optical', 'body' or a matrix."""
    if spec is None:
        return OPTICAL
    if isinstance(spec, str):
        if spec not in MOUNTS:
            raise InputError(f"camera mount {spec!r}: choose {', '.join(MOUNTS)} or give a 4x4 matrix")
        return MOUNTS[spec]
    m = np.asarray(spec, np.float64)
    if m.shape != (4, 4) or not np.allclose(m[:3, :3] @ m[:3, :3].T, np.eye(3), atol=1e-6):
        raise InputError("camera mount must be a 4x4 rigid transform")
    return m


def pose_matrix(pose: Pose) -> np.ndarray:
    """4x4 world-from-pose. A pose without a quaternion is a z-up body turned by its yaw."""
    m = np.eye(4)
    if pose.quat is not None:
        m[:3, :3] = Rotation.from_quat(pose.quat).as_matrix()
    else:
        c, s = math.cos(pose.yaw), math.sin(pose.yaw)
        m[:3, :3] = [[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]
    m[:3, 3] = pose.xyz
    return m


def camera_matrix(pose: Pose, extrinsic: np.ndarray) -> np.ndarray:
    """4x4 world-from-optical-camera."""
    return pose_matrix(pose) @ extrinsic


def back_project(
    depth: np.ndarray, intr: Intrinsics, stride: int, min_range: float, max_range: float
) -> np.ndarray:
    """Camera-frame points (N, 3) of every `stride`-th pixel with a depth in range (metres
    along the optical axis; 0 or NaN = no reading)."""
    h, w = depth.shape
    vs = np.arange(stride // 2, h, stride)
    us = np.arange(stride // 2, w, stride)
    d = np.asarray(depth, np.float32)[np.ix_(vs, us)]
    ok = np.isfinite(d) & (d >= min_range) & (d <= max_range)
    vv, uu = np.nonzero(ok)
    z = d[vv, uu].astype(np.float64)
    x = (us[uu] + 0.5 - intr.cx) / intr.fx * z
    y = (vs[vv] + 0.5 - intr.cy) / intr.fy * z
    return np.stack([x, y, z], axis=1)


def fit_floor(
    points: np.ndarray, cameras: np.ndarray, camera_ups: np.ndarray, max_tilt_deg: float = 45.0
) -> MapFrame:
    """The floor plane of a set of world points seen from `cameras` (M, 3) whose image-up
    directions are `camera_ups` (M, 3).

    The prior "up" is the mean image-up direction. Below the cameras, the lowest height band
    holding at least a quarter of the most populated band is the floor; a least-squares plane
    through its points (tilted at most `max_tilt_deg` from the prior) refines up, twice.
    When no floor is visible, the floor is put at the lowest 1 % of the points (said in
    `MapFrame.method`).
    """
    pts = np.asarray(points, np.float64).reshape(-1, 3)
    prior = np.asarray(camera_ups, np.float64).reshape(-1, 3).mean(axis=0)
    if not np.isfinite(prior).all() or np.linalg.norm(prior) < 0.3:
        raise InputError("cannot tell which way is up: the cameras' orientations disagree")
    u0 = prior / np.linalg.norm(prior)
    if pts.shape[0] < 50:
        raise InputError("too few depth points to find the floor")
    u, method = u0, "lowest points (floor not seen)"
    floor = float(np.percentile(pts @ u0, 1.0))
    for _ in range(3):
        h = pts @ u
        cam_h = float(np.median(np.asarray(cameras, np.float64).reshape(-1, 3) @ u))
        below = h < cam_h - 0.3
        if below.sum() < 50:
            break
        hb = h[below]
        bins = np.arange(hb.min(), hb.max() + 0.04, 0.02)
        if bins.size < 2:
            bins = np.array([hb.min() - 0.01, hb.min() + 0.01])
        counts, edges = np.histogram(hb, bins=bins)
        smooth = np.convolve(counts, np.ones(3), mode="same")
        strong = np.nonzero(smooth >= 0.25 * smooth.max())[0]
        level = float(edges[strong[0]] + edges[strong[0] + 1]) / 2.0
        sel = below & (np.abs(h - level) < 0.05)
        if sel.sum() < 30:
            break
        p = pts[sel]
        for _refine in range(2):  # least squares, then again on the inliers
            c = p.mean(axis=0)
            n = np.linalg.svd(p - c, full_matrices=False)[2][2]
            n = n if n @ u > 0 else -n
            res = (p - c) @ n
            keep = np.abs(res) < 0.03
            if keep.sum() >= 30:
                p = p[keep]
        if math.degrees(math.acos(min(1.0, float(n @ u0)))) > max_tilt_deg:
            break
        u, floor, method = n, float(np.median(p @ n)), "floor-plane fit"
    return MapFrame.from_up(u, floor, method)


@dataclass
class _Pending:
    """A depth frame waiting for the floor fit: its world points and camera position."""

    points: np.ndarray
    camera: np.ndarray
    up: np.ndarray
    source: str
    t: float


@dataclass
class MapStats:
    """What a builder did: frames mapped and skipped (with reasons)."""

    mapped: int = 0
    skipped: dict[str, int] = field(default_factory=dict)

    def skip(self, reason: str) -> None:
        self.skipped[reason] = self.skipped.get(reason, 0) + 1


class MapBuilder:
    """Builds or extends the map in a memory folder from depth frames (a frame sink for
    `ravenmem.ingest.pipeline.ingest`, or called live).

    `intrinsics` is the depth camera's; `extrinsic` the camera mount ('optical', 'body' or a
    4x4). The floor is fitted once, from the first `fit_frames` depth frames, and kept with the
    map, so later frames and later ingests land in the same cells. The map is saved every
    `save_every` frames and on `close()`. An existing map is read at the first frame, not
    before: by then the ingest holds the memory's writer lock, so two writers never interleave.
    """

    def __init__(
        self,
        folder: str | Path,
        intrinsics: Intrinsics | None = None,
        extrinsic: str | np.ndarray | None = None,
        config: MapConfig | None = None,
        fit_frames: int = 30,
        save_every: int = 200,
        rebuild: bool = False,
    ) -> None:
        self.folder = Path(folder)
        self.intrinsics = intrinsics
        self.extrinsic = mount(extrinsic)
        self.fit_frames = max(1, int(fit_frames))
        self.save_every = max(1, int(save_every))
        self.stats = MapStats()
        self.note = ""
        self.grid: OccupancyGrid | None = None
        self.config = config or recording_config()
        self._pending: list[_Pending] = []
        self._dirty = 0
        self._rebuild = rebuild
        self._opened = False
        self._done: dict[str, float] = {}

    def _open(self) -> None:
        """Read the memory's map, if it has one (once, at the first frame)."""
        if self._opened:
            return
        self._opened = True
        if (self.folder / MAP_GRID).is_file() and not self._rebuild:
            grid = OccupancyGrid.load(self.folder)
            if grid.kind != "recorded":
                self.note = f"the memory's map was made by {grid.kind!r}; depth frames leave it as it is"
                return
            self.grid, self.config = grid, grid.config
            self._done = {str(k): float(v) for k, v in grid.meta.get("sources", {}).items()}

    # --- frames ------------------------------------------------------------------------------
    def add(self, frame: Frame) -> bool:
        """Fuse one frame (with `depth` and `pose`) into the map; False when it was skipped."""
        self._open()
        if self.note or frame.depth is None or frame.pose is None:
            return False
        if frame.t <= self._done.get(frame.source, -math.inf):
            self.stats.skip(SKIP_DONE)
            return False
        if self.intrinsics is None:
            self.stats.skip(SKIP_NO_CAMERA)
            return False
        depth = np.asarray(frame.depth, np.float32)
        if depth.ndim != 2:
            self.stats.skip(SKIP_BAD_DEPTH)
            return False
        try:
            intr = self.intrinsics.for_image(depth.shape[1], depth.shape[0])
        except InputError:
            self.stats.skip(SKIP_BAD_DEPTH)
            return False
        cfg = self.config
        cam = camera_matrix(frame.pose, self.extrinsic)
        local = back_project(depth, intr, cfg.stride, cfg.min_range, cfg.max_range)
        world = local @ cam[:3, :3].T + cam[:3, 3]
        item = _Pending(world, cam[:3, 3].copy(), -cam[:3, 1], frame.source, float(frame.t))
        self._done[frame.source] = float(frame.t)
        self.stats.mapped += 1
        if self.grid is None:
            self._pending.append(item)
            if len(self._pending) % self.fit_frames == 0:
                try:
                    self._start()
                except InputError as e:  # too little floor so far: wait for more frames, then give up
                    if len(self._pending) >= 4 * self.fit_frames:
                        self.note, self._pending = f"no map: {e}", []
            return True
        self._fuse(item)
        return True

    def _start(self) -> None:
        """Fit the floor on the frames so far, then fuse them."""
        if not self._pending:
            return
        pts = np.concatenate([p.points[::4] for p in self._pending])
        frame = fit_floor(
            pts, np.stack([p.camera for p in self._pending]), np.stack([p.up for p in self._pending])
        )
        grid = OccupancyGrid(self.config)
        grid.meta = {"kind": "recorded", "frame": frame.as_dict(), "sources": {}}
        if self.intrinsics is not None:
            i = self.intrinsics
            grid.meta["camera"] = {
                "fx": i.fx,
                "fy": i.fy,
                "cx": i.cx,
                "cy": i.cy,
                "width": i.width,
                "height": i.height,
            }
        grid.meta["mount"] = self.extrinsic.tolist()
        self.grid = grid
        pending, self._pending = self._pending, []
        for p in pending:
            self._fuse(p)

    def _fuse(self, p: _Pending) -> None:
        assert self.grid is not None
        integrate_points(self.grid, p.points, p.camera)
        self._dirty += 1
        if self._dirty >= self.save_every:
            self.save()

    # --- saving ------------------------------------------------------------------------------
    def save(self) -> None:
        """Write the map (atomic) with the latest frame time of each source it holds."""
        if self.grid is None:
            return
        self.grid.meta["sources"] = dict(self._done)
        self.grid.save(self.folder)
        self._dirty = 0

    def close(self) -> None:
        """Fit the floor if it was still waiting for frames, fuse, and save."""
        if self.note:
            return
        if self.grid is None and self._pending:
            try:
                self._start()
            except InputError as e:
                self.note = f"no map: {e}"
                self._pending = []
                return
        if self.grid is not None and (self._dirty or self.stats.mapped):
            self.save()

    def summary(self) -> dict[str, Any]:
        """Counts for a report: frames mapped/skipped and the map's cells."""
        out: dict[str, Any] = {"frames_mapped": self.stats.mapped, "skipped": dict(self.stats.skipped)}
        if self.note:
            out["note"] = self.note
        if self.grid is not None:
            out.update(map_counts(self.grid))
        return out


def map_counts(grid: OccupancyGrid) -> dict[str, Any]:
    """Cell size and the number of free, occupied and unknown cells."""
    return {
        "cell_size_m": grid.resolution,
        "free": int(grid.free.sum()),
        "occupied": int(grid.occupied.sum()),
        "unknown": int(grid.unknown.sum()),
    }


def integrate_points(grid: OccupancyGrid, points: np.ndarray, camera: np.ndarray) -> int:
    """Fuse one frame's world points (N, 3) seen from `camera` (3,) into `grid` (whose
    `frame` gives the floor and the map axes). Returns the number of obstacle cells."""
    cfg = grid.config
    fr = grid.frame
    pts = np.asarray(points, np.float64).reshape(-1, 3)
    h = fr.height(pts)
    xy = fr.to_map(pts)
    c2 = fr.to_map(np.asarray(camera, np.float64))[0]
    is_obs = (h > cfg.step_height) & (h <= cfg.obstacle_max)
    is_floor = np.abs(h) <= cfg.step_height
    keep = is_obs | is_floor
    xy, is_obs = xy[keep], is_obs[keep]
    r = cfg.robot_radius
    lo = np.minimum(xy.min(axis=0) if xy.size else c2, c2) - r
    hi = np.maximum(xy.max(axis=0) if xy.size else c2, c2) + r
    grid.ensure(float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1]))
    if len(grid.trajectory) == 0 or np.hypot(*(grid.trajectory[-1] - c2)) > 0.02:
        grid.trajectory = np.vstack([grid.trajectory, c2[None, :].astype(np.float32)])
    grid.mark_free_disc(float(c2[0]), float(c2[1]), min(r, 0.3))
    if xy.size == 0:
        return 0
    h_, w_ = grid.shape
    res = grid.resolution
    rows = np.floor((xy[:, 1] - grid.origin[1]) / res).astype(np.int64)
    cols = np.floor((xy[:, 0] - grid.origin[0]) / res).astype(np.int64)
    flat = rows * w_ + cols
    obs_flat, obs_n = np.unique(flat[is_obs], return_counts=True)
    obs_flat = obs_flat[obs_n >= MIN_POINTS]
    obstacle = np.zeros(h_ * w_, bool)
    obstacle[obs_flat] = True
    targets = np.unique(np.concatenate([flat[~is_obs], obs_flat]))
    # Ray casting. Targets are binned by bearing from the camera, finely enough that two
    # neighbouring rays are at most half a cell apart at the farthest target; one ray per bin,
    # to its farthest target, sampled every half cell, stops at the first obstacle of this
    # frame. A target is reached (seen) when it lies before its bin's first obstacle.
    tr, tc = np.divmod(targets, w_)
    dx = grid.origin[0] + (tc + 0.5) * res - c2[0]
    dy = grid.origin[1] + (tr + 0.5) * res - c2[1]
    length = np.hypot(dx, dy)
    ang = np.arctan2(dy, dx)
    mid = math.atan2(float(np.sin(ang).mean()), float(np.cos(ang).mean()))
    rel = np.arctan2(np.sin(ang - mid), np.cos(ang - mid))
    dtheta = res / (2.0 * max(float(length.max()), res))
    bins = np.floor((rel - rel.min()) / dtheta).astype(np.int64)
    ubins, inv = np.unique(bins, return_inverse=True)
    far = np.zeros(ubins.size)
    np.maximum.at(far, inv, length)
    theta = mid + rel.min() + (ubins + 0.5) * dtheta
    steps = np.arange(int(np.ceil(far.max() / (res / 2.0))) + 1) * (res / 2.0)
    on_ray = steps[None, :] <= far[:, None]
    sx = c2[0] + steps[None, :] * np.cos(theta)[:, None]
    sy = c2[1] + steps[None, :] * np.sin(theta)[:, None]
    sc = np.clip(np.floor((sx - grid.origin[0]) / res).astype(np.int64), 0, w_ - 1)
    sr = np.clip(np.floor((sy - grid.origin[1]) / res).astype(np.int64), 0, h_ - 1)
    sf = sr * w_ + sc
    hit = obstacle[sf] & on_ray & (steps[None, :] > res)  # the camera's own cell never blocks
    first = np.where(hit.any(axis=1), steps[np.argmax(hit, axis=1)], np.inf)  # per bin
    free_flat = np.unique(sf[on_ray & (steps[None, :] < first[:, None])])
    reached = length < first[inv] + res
    free_flat = np.union1d(free_flat, targets[reached & ~obstacle[targets]])
    free_flat = free_flat[~obstacle[free_flat]]
    near = length <= cfg.explore_range
    fr_, fc_ = np.divmod(free_flat, w_)
    or_, oc_ = np.divmod(obs_flat, w_)
    grid._add(fr_, fc_, cfg.l_free)
    grid._add(or_, oc_, cfg.l_occ)
    seen = np.union1d(free_flat, targets[near & reached])
    grid.explored.reshape(-1)[seen] = True
    return int(obs_flat.size)
