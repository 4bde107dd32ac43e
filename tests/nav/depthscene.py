"""Exact depth images of a floor and boxes, for mapper tests: ray casting in numpy.

The scene is given in a z-up "scene" frame (floor z = 0); `world_from_scene` moves it into any
world frame, so that the same scene can be recorded in a world whose up is not z (like TUM's).
"""

from __future__ import annotations

import math

import numpy as np

from ravenmem.types import Intrinsics, Pose

INTR = Intrinsics(200.0, 200.0, 160.0, 120.0, 320, 240)


def look(x: float, y: float, height: float, yaw: float, pitch: float = 0.0) -> np.ndarray:
    """4x4 scene-from-optical-camera at (x, y, height), heading `yaw`, pitched down by `pitch`."""
    fwd = np.array([math.cos(yaw) * math.cos(pitch), math.sin(yaw) * math.cos(pitch), -math.sin(pitch)])
    right = np.array([math.sin(yaw), -math.cos(yaw), 0.0])
    down = np.cross(fwd, right)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = right, down, fwd, (x, y, height)
    return m


def render(
    cam: np.ndarray, boxes: list[tuple[float, float, float, float, float]], intr: Intrinsics = INTR
) -> np.ndarray:
    """Depth (metres along the optical axis, 0 = nothing) from scene-from-camera `cam` of the
    floor z = 0 and axis-aligned boxes (xmin, ymin, xmax, ymax, height)."""
    v, u = np.mgrid[0 : intr.height, 0 : intr.width].astype(np.float64) + 0.5
    rays = np.stack([(u - intr.cx) / intr.fx, (v - intr.cy) / intr.fy, np.ones_like(u)], -1)  # z = 1
    d = rays @ cam[:3, :3].T  # scene direction per unit of depth
    o = cam[:3, 3]
    best = np.full(u.shape, np.inf)
    with np.errstate(divide="ignore", invalid="ignore"):
        tf = -o[2] / d[..., 2]
        best = np.where((d[..., 2] < 0) & (tf > 0), tf, best)
        for x0, y0, x1, y1, hz in boxes:
            lo, hi = np.array([x0, y0, 0.0]), np.array([x1, y1, hz])
            t1, t2 = (lo - o) / d, (hi - o) / d
            tmin = np.nanmax(np.minimum(t1, t2), axis=-1)
            tmax = np.nanmin(np.maximum(t1, t2), axis=-1)
            hit = (tmax >= tmin) & (tmax > 0)
            best = np.where(hit & (tmin > 0) & (tmin < best), tmin, best)
    return np.where(np.isfinite(best), best, 0.0).astype(np.float32)


def pose_of(world_from_cam: np.ndarray) -> Pose:
    """A Pose (with quaternion) for a 4x4 transform."""
    from scipy.spatial.transform import Rotation

    q = Rotation.from_matrix(world_from_cam[:3, :3]).as_quat()
    x, y, z = world_from_cam[:3, 3]
    return Pose.from_quaternion(float(x), float(y), float(z), *map(float, q))
