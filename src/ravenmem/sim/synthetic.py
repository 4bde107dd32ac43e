"""A tiny built-in world: walls and boxes on a plane, rendered by ray casting in numpy.

It needs no simulator package, so the whole explore -> remember -> navigate loop can be tested
anywhere. Walls are vertical segments `wall_height` tall, objects are square boxes with a class
name, flat-shaded (an image embedder recognises little there) or with a photograph printed on
each side (`Box.photo`: the `gallery` world, real pictures an ImageNet embedder knows). The
worlds themselves and the `synthetic:NAME` environments are `ravenmem.sim.worlds`.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace
from functools import cache
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..types import Intrinsics, Pose
from .base import Observation, RobotSpec, SceneObject


@dataclass(frozen=True)
class Box:
    kind: str
    x: float
    y: float
    half: float = 0.3
    height: float = 0.8
    color: tuple[int, int, int] = (200, 40, 40)
    photo: str | None = None  # a picture printed on every side: a name in `sim/photos/`
    half_y: float | None = None  # half its depth along y when not `half` (a thin panel)


@dataclass
class World:
    walls: np.ndarray  # (n, 4) x1, y1, x2, y2 metres
    boxes: list[Box] = field(default_factory=list)
    start: tuple[float, float, float] = (0.0, 0.0, 0.0)  # x, y, yaw
    wall_height: float = 2.5
    camera: tuple[int, int] = (160, 120)  # width, height of the pictures (pixels)


def _rect(x0: float, y0: float, x1: float, y1: float) -> list[tuple[float, float, float, float]]:
    return [(x0, y0, x1, y0), (x1, y0, x1, y1), (x1, y1, x0, y1), (x0, y1, x0, y0)]


def rooms_world() -> World:
    """Two 8 x 6 m rooms joined by a 1.5 m doorway, with three coloured boxes."""
    walls = [(0, 0, 16, 0), (16, 0, 16, 6), (16, 6, 0, 6), (0, 6, 0, 0), (8, 0, 8, 2.25), (8, 3.75, 8, 6)]
    boxes = [
        Box("RedBox", 3.0, 4.5, color=(210, 40, 40)),
        Box("BlueBox", 12.5, 1.5, color=(40, 60, 210)),
        Box("GreenBox", 14.0, 4.8, half=0.4, height=1.0, color=(40, 170, 60)),
    ]
    return World(np.asarray(walls, np.float64), boxes, start=(2.0, 1.5, 0.5))


class SyntheticEnv:
    """A unicycle robot in a `World`; `step` advances `dt` seconds. Boxes can be moved,
    removed and added between (or during) episodes, to test a memory of a world that changes;
    `start_time` (epoch seconds, None = the wall clock) is when the next `reset` starts."""

    def __init__(
        self,
        world: World | None = None,
        name: str = "synthetic:rooms",
        width: int | None = None,
        height: int | None = None,
        hfov_deg: float = 90.0,
        dt: float = 0.2,
        max_speed: float = 1.0,
        start_time: float | None = None,
        max_depth: float = 20.0,
    ) -> None:
        self.world = world or rooms_world()
        self.name = name
        self.intrinsics = Intrinsics.from_fov(
            width or self.world.camera[0], height or self.world.camera[1], hfov_deg
        )
        self.robot = RobotSpec(
            radius=0.25, height=1.2, step_height=0.1, camera_height=0.8, max_speed=max_speed
        )
        self.dt = float(dt)
        self.max_depth = float(max_depth)
        self.start_time = start_time
        self._boxes: dict[int, Box] = dict(enumerate(self.world.boxes))  # ids stay when boxes go
        self._build()
        self._x, self._y, self._yaw = self.world.start
        self._steps = 0
        self._t0 = 0.0

    def _build(self) -> None:
        segs, tops, cols, owner, tex = [], [], [], [], []
        for i, w in enumerate(self.world.walls):
            segs.append(w)
            tops.append(self.world.wall_height)
            shade = 150 + (i * 37) % 90
            cols.append((shade, shade - 20, shade - 50))
            owner.append(-1)
            tex.append(-1)
        self._photos: list[np.ndarray] = []
        for j, b in self._boxes.items():
            t = -1
            if b.photo is not None:
                self._photos.append(photo(b.photo))
                t = len(self._photos) - 1
            hy = b.half if b.half_y is None else b.half_y
            for s in _rect(b.x - b.half, b.y - hy, b.x + b.half, b.y + hy):
                segs.append(s)
                tops.append(b.height)
                cols.append(b.color)
                owner.append(j)
                tex.append(t)
        self._tex = np.asarray(tex, np.int64)
        self._segs = np.asarray(segs, np.float64).reshape(-1, 4)
        self._tops = np.asarray(tops, np.float64)
        self._cols = np.asarray(cols, np.float64)
        self._owner = np.asarray(owner, np.int64)

    # --- a world that changes -------------------------------------------------------------
    def move_object(self, obj_id: int, x: float, y: float) -> None:
        """Put box `obj_id` somewhere else (it keeps its id, kind and looks)."""
        self._boxes[self._box_id(obj_id)] = replace(self._boxes[obj_id], x=float(x), y=float(y))
        self._build()

    def remove_object(self, obj_id: int) -> None:
        """Take box `obj_id` out of the world (its id is not reused)."""
        del self._boxes[self._box_id(obj_id)]
        self._build()

    def add_object(self, box: Box) -> int:
        """Put a new box into the world; returns its id."""
        new = max(self._boxes, default=len(self.world.boxes) - 1) + 1
        self._boxes[new] = box
        self._build()
        return new

    def _box_id(self, obj_id: int) -> int:
        if obj_id not in self._boxes:
            raise InputError(f"{self.name}: no object {obj_id}; objects: {sorted(self._boxes)}")
        return obj_id

    # --- protocol -------------------------------------------------------------------------
    def reset(self) -> Observation:
        self._x, self._y, self._yaw = self.world.start
        self._steps = 0
        self._t0 = time.time() if self.start_time is None else float(self.start_time)
        return self.observe()

    def observe(self) -> Observation:
        rgb, depth, boxes = self.render(self._x, self._y, self._yaw)
        pose = Pose(self._x, self._y, self.robot.camera_height, self._yaw)
        return Observation(
            floor_z=0.0,
            rgb=rgb,
            depth=depth,
            pose=pose,
            t=self._t0 + self._steps * self.dt,
            step=self._steps,
            visible=tuple(sorted(boxes)),
            visible_boxes=boxes,
        )

    def view_from(self, x: float, y: float, yaw: float) -> Observation:
        """What the camera sees from (x, y) facing `yaw`, without moving the robot (query
        pictures and tests)."""
        rgb, depth, boxes = self.render(x, y, yaw)
        pose = Pose(x, y, self.robot.camera_height, yaw)
        return Observation(
            rgb=rgb,
            depth=depth,
            pose=pose,
            t=self._t0,
            floor_z=0.0,
            visible=tuple(sorted(boxes)),
            visible_boxes=boxes,
        )

    def step(self, forward: float, turn: float) -> Observation:
        self._yaw = math.atan2(math.sin(self._yaw + turn), math.cos(self._yaw + turn))
        dist = max(-1.0, min(1.0, float(forward))) * self.robot.max_speed * self.dt
        nx, ny = self._x + dist * math.cos(self._yaw), self._y + dist * math.sin(self._yaw)
        if self._clearance(nx, ny) > self.robot.radius:  # a bump stops the robot
            self._x, self._y = nx, ny
        self._steps += 1
        return self.observe()

    def objects(self) -> list[SceneObject]:
        return [SceneObject(i, b.kind, b.x, b.y, 0.0) for i, b in sorted(self._boxes.items())]

    def close(self) -> None:
        return None

    def wall_segments(self, solid_only: bool = True) -> np.ndarray:
        """Every segment the robot cannot cross (walls and box sides), metres."""
        return self._segs.copy()

    # --- geometry -------------------------------------------------------------------------
    def _clearance(self, x: float, y: float) -> float:
        s = self._segs
        ex, ey = s[:, 2] - s[:, 0], s[:, 3] - s[:, 1]
        t = np.clip(
            ((x - s[:, 0]) * ex + (y - s[:, 1]) * ey) / np.maximum(ex * ex + ey * ey, 1e-12), 0.0, 1.0
        )
        return float(np.min(np.hypot(x - s[:, 0] - t * ex, y - s[:, 1] - t * ey)))

    def render(
        self, x: float, y: float, yaw: float, k_hits: int = 4
    ) -> tuple[np.ndarray, np.ndarray, dict[int, tuple[int, int, int, int]]]:
        """RGB, z-depth (metres, 0 = nothing within `max_depth`) and the visible boxes' places in
        the picture ({box id: (x, y, width, height)} in pixels) from a pose."""
        intr = self.intrinsics
        h_cam = self.robot.camera_height
        u = np.arange(intr.width) + 0.5
        ru = (u - intr.cx) / intr.fx
        fx_, fy_ = math.cos(yaw), math.sin(yaw)
        dx = fx_ + ru * fy_  # forward + ru * right, right = (sin, -cos)
        dy = fy_ - ru * fx_
        s = self._segs
        ex, ey = s[:, 2] - s[:, 0], s[:, 3] - s[:, 1]
        px, py = s[:, 0] - x, s[:, 1] - y
        den = dx[:, None] * ey[None, :] - dy[:, None] * ex[None, :]
        with np.errstate(divide="ignore", invalid="ignore"):
            sd = (px[None, :] * ey[None, :] - py[None, :] * ex[None, :]) / den
            td = (px[None, :] * dy[:, None] - py[None, :] * dx[:, None]) / den
        ok = (np.abs(den) > 1e-12) & (sd > 1e-6) & (td >= 0.0) & (td <= 1.0) & (sd <= self.max_depth)
        sd = np.where(ok, sd, np.inf)
        k = min(k_hits, s.shape[0])
        order = np.argsort(sd, axis=1)[:, :k]  # (W, k) nearest segments per column
        hs = np.take_along_axis(sd, order, axis=1)
        along = np.take_along_axis(np.where(ok, td, 0.0), order, axis=1)  # where on the segment
        v = np.arange(intr.height) + 0.5
        down = (v - intr.cy) / intr.fy
        with np.errstate(divide="ignore"):
            s_floor = np.where(down > 0, h_cam / down, np.inf)
        s_floor = np.where(s_floor <= self.max_depth, s_floor, np.inf)
        depth = np.zeros((intr.height, intr.width))
        seg = np.full((intr.height, intr.width), -1, np.int64)
        done = np.zeros((intr.height, intr.width), bool)
        tex_u = np.zeros((intr.height, intr.width))
        tex_h = np.zeros((intr.height, intr.width))
        for j in range(k):
            sj = hs[:, j][None, :]
            hj = h_cam - sj * down[:, None]
            top = self._tops[order[:, j]][None, :]
            hit = ~done & np.isfinite(sj) & (sj < s_floor[:, None]) & (hj >= 0.0) & (hj <= top)
            depth = np.where(hit, sj, depth)
            seg = np.where(hit, order[:, j][None, :], seg)
            tex_u = np.where(hit, along[:, j][None, :], tex_u)
            tex_h = np.where(hit, hj / top, tex_h)
            done |= hit
        floor = ~done & np.isfinite(s_floor)[:, None]
        depth = np.where(floor, s_floor[:, None], depth)
        rgb = np.empty((intr.height, intr.width, 3))
        rgb[:] = (215, 225, 235)  # sky / ceiling
        shade = 1.0 / (1.0 + 0.08 * depth)
        wall_px = seg >= 0
        rgb[wall_px] = self._cols[seg[wall_px]] * (0.4 + 0.6 * shade[wall_px, None])
        self._print_photos(rgb, seg, tex_u, tex_h, shade)
        if floor.any():
            sf = np.broadcast_to(s_floor[:, None], floor.shape)[floor]
            uu = np.broadcast_to(ru[None, :], floor.shape)[floor]
            wx = x + sf * fx_ + sf * uu * fy_
            wy = y + sf * fy_ - sf * uu * fx_
            checker = (np.floor(wx) + np.floor(wy)) % 2 == 0
            base = np.where(checker, 120.0, 95.0)
            rgb[floor] = (base * (0.5 + 0.5 * shade[floor]))[:, None] * np.array([1.0, 0.95, 0.9])
        owners = self._owner[seg[wall_px]]
        rows, cols = np.nonzero(wall_px)
        boxes: dict[int, tuple[int, int, int, int]] = {}
        for i in np.unique(owners[owners >= 0]):
            m = owners == i
            if m.sum() >= 4:
                r, c = rows[m], cols[m]
                boxes[int(i)] = (int(c.min()), int(r.min()), int(np.ptp(c)) + 1, int(np.ptp(r)) + 1)
        return np.clip(rgb, 0, 255).astype(np.uint8), depth.astype(np.float32), boxes

    def _print_photos(
        self, rgb: np.ndarray, seg: np.ndarray, u: np.ndarray, h: np.ndarray, shade: np.ndarray
    ) -> None:
        """Paint each photo box's picture onto the pixels of its sides, as large as fits with its
        shape kept, centred (nearest texel; a side runs left to right as seen from outside, its
        top is the picture's top row)."""
        tid = np.where(seg >= 0, self._tex[np.maximum(seg, 0)], -1)
        for t, pic in enumerate(self._photos):
            m = tid == t
            if not m.any():
                continue
            s = self._segs[seg[m]]
            side = np.hypot(s[:, 2] - s[:, 0], s[:, 3] - s[:, 1]) / self._tops[seg[m]]  # width / height
            ph, pw = pic.shape[:2]
            fw = np.minimum(1.0, (pw / ph) / side)  # share of the side's width the picture covers
            fh = np.minimum(1.0, side / (pw / ph))
            pu = (u[m] - 0.5) / fw + 0.5
            pv = (0.5 - h[m]) / fh + 0.5
            inside = (pu >= 0) & (pu < 1) & (pv >= 0) & (pv < 1)
            cu = np.clip((pu * pw).astype(np.int64), 0, pw - 1)
            cv = np.clip((pv * ph).astype(np.int64), 0, ph - 1)
            px = rgb[m]
            px[inside] = pic[cv[inside], cu[inside]] * (0.75 + 0.25 * shade[m][inside, None])
            rgb[m] = px


@cache
def photo(name: str) -> np.ndarray:
    """A picture from `sim/photos/` (RGB uint8; see its README for sources and licence)."""
    from PIL import Image

    path = Path(__file__).with_name("photos") / f"{name}.jpg"
    if not path.is_file():
        raise InputError(f"synthetic world: no photo {name!r} in {path.parent}")
    with Image.open(path) as im:
        return np.asarray(im.convert("RGB"), dtype=np.float64)
