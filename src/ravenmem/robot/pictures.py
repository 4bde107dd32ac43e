"""Query pictures for "where did you see this?": a view of the object rendered by the simulator
from a place the robot never stored a keyframe at (like a photo a person took of it).

The viewpoint is a free, reachable-looking cell of the robot's own map between `near` metres
of the object, with a clear line of sight on the map, at least `min_gap` metres from every
keyframe position (so the picture is not one of the memories), the nearest such to a keyframe
(a view a robot passing by could have had), with a clear line of sight on the map if any.
Items the robot picked up while exploring are gone from the running episode: reset the
environment before asking for pictures. The picture is the central `crop` of the view,
centred on the object as far as the frame allows.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from PIL import Image

from ..nav.astar import line_of_sight
from ..nav.grid import OccupancyGrid
from ..sim.base import SceneObject


def query_picture(
    env: Any,
    grid: OccupancyGrid,
    obj: SceneObject,
    keyframes: np.ndarray,
    radius: float,
    near: tuple[float, float] = (1.5, 5.0),
    min_gap: float = 1.0,
    crop: float = 0.8,
    min_px: int = 60,
    tries: int = 40,
) -> np.ndarray | None:
    """A picture of `obj` (RGB uint8), or None when the simulator cannot render views or no
    viewpoint shows it. `keyframes` are the memories' (x, y) positions."""
    if not hasattr(env, "view_from"):
        return None
    trav = grid.traversable(radius)
    rr, cc = np.nonzero(trav)
    if rr.size == 0:
        return None
    wx = grid.origin[0] + (cc + 0.5) * grid.resolution
    wy = grid.origin[1] + (rr + 0.5) * grid.resolution
    d = np.hypot(wx - obj.x, wy - obj.y)
    cand = np.nonzero((d >= near[0]) & (d <= near[1]))[0]
    if cand.size == 0:
        return None
    kf = np.asarray(keyframes, np.float64).reshape(-1, 2)
    gap = (
        np.min(np.hypot(wx[cand, None] - kf[None, :, 0], wy[cand, None] - kf[None, :, 1]), axis=1)
        if kf.size
        else np.full(cand.size, np.inf)
    )
    keep = gap >= min_gap
    cand, gap = cand[keep], gap[keep]
    see = ~grid.occupied
    goal = grid.world_to_cell(obj.x, obj.y)
    if grid.contains(goal):  # the object itself (a solid one is an obstacle) does not hide itself
        see[max(0, goal[0] - 2) : goal[0] + 3, max(0, goal[1] - 2) : goal[1] + 3] = True
    order = cand[np.argsort(gap, kind="stable")]
    if grid.contains(goal):  # views with a clear line on the map first, the others after
        clear = np.array([line_of_sight(see, (int(rr[i]), int(cc[i])), goal) for i in order], bool)
        order = np.concatenate([order[clear], order[~clear]])
    for i in order[:tries]:
        obs = env.view_from(float(wx[i]), float(wy[i]), math.atan2(obj.y - wy[i], obj.x - wx[i]))
        box = obs.visible_boxes.get(obj.id)
        if box is None or box[2] * box[3] < min_px:
            continue
        return _crop(obs.rgb, box, crop)
    return None


def _crop(rgb: np.ndarray, box: tuple[int, int, int, int], frac: float) -> np.ndarray:
    """The central `frac` of the picture, shifted to centre the box as far as it can."""
    h, w = rgb.shape[:2]
    cw, ch = max(2, int(w * frac)), max(2, int(h * frac))
    bx, by, bw, bh = box
    x0 = int(min(max(bx + bw / 2 - cw / 2, 0), w - cw))
    y0 = int(min(max(by + bh / 2 - ch / 2, 0), h - ch))
    out = rgb[y0 : y0 + ch, x0 : x0 + cw]
    return np.asarray(Image.fromarray(np.ascontiguousarray(out)).resize((w, h), Image.Resampling.BILINEAR))
