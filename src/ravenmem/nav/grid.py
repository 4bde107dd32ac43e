"""A 2-D occupancy grid built from depth images, kept with the memory it was explored with.

Cells hold log-odds of being occupied, plus two masks: `known` (some ray reached the cell) and
`explored` (the cell was inside the camera's field of view and within `explore_range`, the
area a person would call "looked at"). Unknown stays distinct from free: planners never drive
through cells nobody has seen. Row index grows with map y, column index with map x; the
grid grows by itself when the robot sees past its edge.

Maps built by exploring a simulator use world x, y directly; maps built from a recording carry
a `MapFrame` (the fitted floor plane and the map's axes in the recording's world frame) in
`meta["frame"]`. On disk, `map.npz` holds the arrays and the metadata (one file, replaced
atomically, so a crash never pairs new arrays with old metadata); `map.json` repeats the
metadata for people and other tools.
"""

from __future__ import annotations

import io
import json
import math
import warnings
from dataclasses import asdict, dataclass, fields
from pathlib import Path
from typing import Any

import numpy as np
from PIL import Image, UnidentifiedImageError
from scipy import ndimage

from ..errors import InputError
from ..fsio import MAX_IMAGE, atomic_open, atomic_write_json, read_bounded
from ..memory.folder import MAP_GRID, MAP_META
from ..types import Intrinsics, Pose
from .base import Cell
from .frame import MapFrame

FORMAT_VERSION = 2
MAX_MAP_CELLS = 100_000_000  # a map picture's pixels (10,000 x 10,000: 500 m square at 5 cm)
_GROW = 32  # cells added at once when the map grows


@dataclass
class MapConfig:
    """How depth becomes occupancy. Heights are metres above the floor the robot stands on.

    A cell is an obstacle when the points that fall in it in one image span more than
    `step_height` vertically (a wall, a post, a ledge), so stairs and ramps the robot can
    climb stay free even when they rise above it. Points higher than `obstacle_max` pass over
    the robot and are ignored. Depth beyond `max_range` is not trusted. `stride` subsamples
    pixels (the map resolution is far coarser than the image). With `require_floor` the robot
    only drives where it has seen floor (or stood): free space that a ray merely crossed, such
    as the hidden floor beyond the rim of a pit, is not traversable.
    """

    resolution: float = 0.25
    step_height: float = 0.2
    obstacle_max: float = 1.8
    max_range: float = 10.0
    min_range: float = 0.05
    explore_range: float = 5.0
    stride: int = 4
    l_occ: float = 0.85
    l_free: float = -0.4
    l_clamp: float = 4.0
    require_floor: bool = True
    robot_radius: float = 0.25

    def __post_init__(self) -> None:
        if self.resolution <= 0 or self.max_range <= 0 or self.stride < 1 or self.robot_radius < 0:
            raise InputError(f"bad map config: {self}")
        if self.obstacle_max <= self.step_height:
            raise InputError(
                f"bad map config: obstacle_max {self.obstacle_max} <= step_height {self.step_height}"
            )

    @classmethod
    def for_body(
        cls,
        step_height: float,
        height: float,
        resolution: float = 0.25,
        max_range: float = 10.0,
        radius: float = 0.25,
    ) -> MapConfig:
        """Obstacles are what a robot body can neither step over nor pass under."""
        return cls(
            resolution=resolution,
            step_height=step_height + 0.05,
            obstacle_max=height,
            max_range=max_range,
            robot_radius=radius,
        )

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> MapConfig:
        """Settings saved with a map; unknown keys (from a newer version) are ignored."""
        names = {f.name for f in fields(cls)}
        return cls(**{k: v for k, v in d.items() if k in names})


class OccupancyGrid:
    """Log-odds occupancy grid with known/explored masks; world frame in metres."""

    def __init__(
        self,
        config: MapConfig | None = None,
        origin: tuple[float, float] = (0.0, 0.0),
        shape: tuple[int, int] = (0, 0),
    ) -> None:
        self.config = config or MapConfig()
        self.resolution = float(self.config.resolution)
        self.origin = (float(origin[0]), float(origin[1]))
        self.logodds = np.zeros(shape, np.float32)
        self.known = np.zeros(shape, bool)
        self.explored = np.zeros(shape, bool)
        self.elevation = np.full(shape, np.nan, np.float32)  # floor height (m), NaN = not seen
        self.trajectory = np.zeros((0, 2), np.float32)  # where the robot/camera went, map metres
        self.meta: dict[str, Any] = {"kind": "explored"}  # how the map was made (saved with it)
        self.version = 0
        self._trav_cache: tuple[tuple, np.ndarray] | None = None

    # --- geometry -------------------------------------------------------------------------
    @property
    def frame(self) -> MapFrame:
        """Where the map lies in the world (world x, y and z-up for explored maps)."""
        f = self.meta.get("frame")
        return MapFrame.from_dict(f) if f else MapFrame()

    @property
    def kind(self) -> str:
        """'explored' (a simulator's explorer built it) or 'recorded' (from depth frames), or
        'imported' (a Nav2 map_server map)."""
        return str(self.meta.get("kind", "explored"))

    @property
    def shape(self) -> tuple[int, int]:
        return (int(self.logodds.shape[0]), int(self.logodds.shape[1]))

    def world_to_cell(self, x: float, y: float) -> Cell:
        return (
            int(math.floor((y - self.origin[1]) / self.resolution)),
            int(math.floor((x - self.origin[0]) / self.resolution)),
        )

    def cell_to_world(self, cell: Cell) -> tuple[float, float]:
        """World coordinates of a cell's centre."""
        return (
            self.origin[0] + (cell[1] + 0.5) * self.resolution,
            self.origin[1] + (cell[0] + 0.5) * self.resolution,
        )

    def contains(self, cell: Cell) -> bool:
        return 0 <= cell[0] < self.shape[0] and 0 <= cell[1] < self.shape[1]

    def extent(self) -> tuple[float, float, float, float]:
        """(xmin, xmax, ymin, ymax) in metres, for plotting."""
        h, w = self.shape
        x0, y0 = self.origin
        return (x0, x0 + w * self.resolution, y0, y0 + h * self.resolution)

    def ensure(self, xmin: float, ymin: float, xmax: float, ymax: float) -> None:
        """Grow the arrays (keeping every cell's world position) so the box fits inside."""
        res = self.resolution
        h, w = self.shape
        if h == 0 or w == 0:
            c0 = math.floor(xmin / res) - _GROW
            r0 = math.floor(ymin / res) - _GROW
            self.origin = (c0 * res, r0 * res)
            nh = math.floor(ymax / res) + _GROW - r0 + 1
            nw = math.floor(xmax / res) + _GROW - c0 + 1
            self.logodds = np.zeros((nh, nw), np.float32)
            self.known = np.zeros((nh, nw), bool)
            self.explored = np.zeros((nh, nw), bool)
            self.elevation = np.full((nh, nw), np.nan, np.float32)
            self.touch()
            return
        r_lo, c_lo = self.world_to_cell(xmin, ymin)
        r_hi, c_hi = self.world_to_cell(xmax, ymax)
        pad_top = _GROW if r_lo < 0 else 0
        pad_left = _GROW if c_lo < 0 else 0
        pad_top += max(0, -r_lo)
        pad_left += max(0, -c_lo)
        pad_bottom = max(0, r_hi - (h - 1)) + (_GROW if r_hi >= h else 0)
        pad_right = max(0, c_hi - (w - 1)) + (_GROW if c_hi >= w else 0)
        if not (pad_top or pad_left or pad_bottom or pad_right):
            return
        pads = ((pad_top, pad_bottom), (pad_left, pad_right))
        self.logodds = np.pad(self.logodds, pads)
        self.known = np.pad(self.known, pads)
        self.explored = np.pad(self.explored, pads)
        self.elevation = np.pad(self.elevation, pads, constant_values=np.nan)
        self.origin = (self.origin[0] - pad_left * res, self.origin[1] - pad_top * res)
        self.touch()

    # --- states ---------------------------------------------------------------------------
    @property
    def occupied(self) -> np.ndarray:
        return self.known & (self.logodds > 0.0)

    def ledges(self) -> np.ndarray:
        """Cells whose floor differs from a neighbour's by more than `step_height`: the edge of
        a pit or a platform. The robot could drop down but not climb back, so it never crosses.
        Floor heights come from the camera (floor points) and from the robot itself (the floor
        under its footprint), so a fall the camera did not foresee still leaves a ledge behind."""
        e = self.elevation
        out = np.zeros(e.shape, bool)
        step = self.config.step_height
        with np.errstate(invalid="ignore"):
            for k in (1,):  # 4-neighbours only: on stairs, cells two apart may differ by two risers
                dv = np.abs(e[k:, :] - e[:-k, :]) > step
                dh = np.abs(e[:, k:] - e[:, :-k]) > step
                out[k:, :] |= dv
                out[:-k, :] |= dv
                out[:, k:] |= dh
                out[:, :-k] |= dh
        return out

    @property
    def blocked(self) -> np.ndarray:
        """Where the robot cannot be: obstacles and ledges."""
        return self.occupied | self.ledges()

    def blocked_at(self, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
        """`blocked` for a few cells only (cheap enough to check a path at every step)."""
        rows, cols = np.asarray(rows), np.asarray(cols)
        out = self.occupied[rows, cols].copy()
        e = self.elevation
        h, w = e.shape
        with np.errstate(invalid="ignore"):
            for dr, dc in ((1, 0), (-1, 0), (0, 1), (0, -1)):
                rr, cc = np.clip(rows + dr, 0, h - 1), np.clip(cols + dc, 0, w - 1)
                out |= np.abs(e[rows, cols] - e[rr, cc]) > self.config.step_height
        return out

    @property
    def free(self) -> np.ndarray:
        return self.known & (self.logodds <= 0.0)

    @property
    def unknown(self) -> np.ndarray:
        return ~self.known

    def inflated(self, radius: float) -> np.ndarray:
        """Cells whose centre lies within `radius` metres of an occupied cell (or is one):
        where the robot's centre must not go. Exact Euclidean distance, not a square kernel."""
        occ = self.blocked
        if not occ.any():
            return occ
        dist = ndimage.distance_transform_edt(~occ) * self.resolution
        return np.asarray(dist <= radius)

    def traversable(self, radius: float) -> np.ndarray:
        """Free cells farther than `radius` from every obstacle: where the robot's centre may go.
        Cached until the map changes (exploration asks several times per map update)."""
        key = (self.version, float(radius), self.shape)
        if self._trav_cache is None or self._trav_cache[0] != key:
            ok = self.free & ~self.inflated(radius)
            if self.config.require_floor:
                ok &= self.floor_seen()
            self._trav_cache = (key, ok)
        return self._trav_cache[1].copy()

    def floor_seen(self) -> np.ndarray:
        """Cells whose floor height is known: seen, stood on, or continuous between the two."""
        return np.isfinite(self.elevation)

    def touch(self) -> None:
        """Note that the arrays changed (invalidates cached traversability)."""
        self.version += 1

    # --- updates --------------------------------------------------------------------------
    def _add(self, rows: np.ndarray, cols: np.ndarray, delta: float) -> None:
        if rows.size == 0:
            return
        flat = np.unique(rows * self.shape[1] + cols)
        lo = self.logodds.reshape(-1)
        lo[flat] = np.clip(lo[flat] + delta, -self.config.l_clamp, self.config.l_clamp)
        self.known.reshape(-1)[flat] = True
        self.touch()

    def mark_free_disc(self, x: float, y: float, radius: float, floor_z: float | None = None) -> None:
        """The robot's own footprint is free (the camera cannot see its feet), at `floor_z`."""
        self.ensure(x - radius, y - radius, x + radius, y + radius)
        r0, c0 = self.world_to_cell(x - radius, y - radius)
        r1, c1 = self.world_to_cell(x + radius, y + radius)
        rr, cc = np.mgrid[r0 : r1 + 1, c0 : c1 + 1]
        cx, cy = self.cell_to_world((0, 0))
        wx = cx + cc * self.resolution
        wy = cy + rr * self.resolution
        m = (wx - x) ** 2 + (wy - y) ** 2 <= radius * radius
        sel = m & (self.logodds[rr, cc] <= 0.0)
        self.logodds[rr[sel], cc[sel]] = np.minimum(self.logodds[rr[sel], cc[sel]], self.config.l_free)
        self.known[rr[m], cc[m]] = True
        self.explored[rr[m], cc[m]] = True
        if floor_z is not None:
            self.elevation[rr[m], cc[m]] = floor_z
        self.touch()

    def mark_blocked(self, x: float, y: float, heading: float, distance: float, spread: float = 0.6) -> None:
        """Record an obstacle the camera cannot see but the robot bumped into (an invisible
        wall, a railing): cells on a short arc `distance` ahead of it along `heading`."""
        angles = heading + np.linspace(-spread, spread, 7)
        bx, by = x + distance * np.cos(angles), y + distance * np.sin(angles)
        self.ensure(float(bx.min()), float(by.min()), float(bx.max()), float(by.max()))
        r, c = self._cells(bx, by)
        self.logodds[r, c] = self.config.l_clamp
        self.known[r, c] = True
        self.touch()

    def integrate(self, depth: np.ndarray, pose: Pose, intr: Intrinsics, camera_height: float) -> int:
        """Fuse one depth image (metres along the optical axis, 0/NaN = no reading) taken from
        `pose` (yaw = heading; the camera looks level) into the map. Returns obstacle cells seen.

        Each pixel column is one ray: cells before its nearest obstacle point are free, the
        obstacle's cell is occupied; a column with no obstacle is free up to its farthest point.
        Free space is thus only claimed where the camera really saw floor or a wall.
        """
        cfg = self.config
        depth = np.asarray(depth, np.float32)
        if depth.shape != (intr.height, intr.width):
            raise InputError(f"depth image is {depth.shape}, camera is {intr.height}x{intr.width}")
        s = cfg.stride
        vs = np.arange(s // 2, intr.height, s, dtype=np.float32)
        us = np.arange(s // 2, intr.width, s, dtype=np.float32)
        d = depth[s // 2 :: s, s // 2 :: s][: vs.size, : us.size]
        height = camera_height - (vs[:, None] - intr.cy) / intr.fy * d  # above the robot's floor
        pts = np.isfinite(d) & (d > cfg.min_range) & (d <= cfg.max_range) & (height <= cfg.obstacle_max)
        d = np.where(pts, d, 0.0)
        xr = (us[None, :] - intr.cx) / intr.fx * d  # metres to the right of the optical axis
        rho = np.hypot(d, xr)
        reach = float(np.max(rho, initial=0.0)) + self.resolution
        self.ensure(pose.x - reach, pose.y - reach, pose.x + reach, pose.y + reach)

        cy_, sy_ = math.cos(pose.yaw), math.sin(pose.yaw)
        px = pose.x + d * cy_ + xr * sy_
        py = pose.y + d * sy_ - xr * cy_
        w = self.shape[1]
        col = np.floor((px - self.origin[0]) / self.resolution).astype(np.int64)
        row = np.floor((py - self.origin[1]) / self.resolution).astype(np.int64)
        flat = np.where(pts, row * w + col, -1)
        obstacle = np.zeros_like(pts)
        if pts.any():
            f, hv = flat[pts], height[pts]
            cells, inv = np.unique(f, return_inverse=True)
            lo = np.full(cells.size, np.inf)
            hi = np.full(cells.size, -np.inf)
            np.minimum.at(lo, inv, hv)
            np.maximum.at(hi, inv, hv)
            tall = (hi - lo) > cfg.step_height
            obstacle[pts] = tall[inv]
            # floor heights (world z) of cells with no vertical structure and no higher than a
            # step: for ledge detection (higher "flat" cells are slices of walls, or platforms
            # whose rim the spread rule already marks as an obstacle)
            flat = ~tall & (hi <= cfg.step_height)
            if flat.any():
                self.elevation.reshape(-1)[cells[flat]] = (pose.z - camera_height + hi[flat]).astype(
                    np.float32
                )
        hit_range = np.where(obstacle, rho, np.inf).min(axis=0)
        open_range = np.where(pts & ~obstacle, rho, 0.0).max(axis=0)
        free_range = np.where(np.isfinite(hit_range), hit_range - self.resolution, open_range)
        bearing = pose.yaw - np.arctan((us - intr.cx) / intr.fx)

        step = self.resolution / 2.0
        t = np.arange(0.0, cfg.max_range + step, step, dtype=np.float32)
        along = t[:, None] <= free_range[None, :]
        fx_ = pose.x + t[:, None] * np.cos(bearing)[None, :]
        fy_ = pose.y + t[:, None] * np.sin(bearing)[None, :]
        fr, fc = self._cells(fx_[along], fy_[along])
        seen = along & (t[:, None] <= cfg.explore_range)
        er, ec = self._cells(fx_[seen], fy_[seen])
        self._fill_floor(
            pts & ~obstacle & (height <= cfg.step_height),
            rho,
            height,
            t,
            along,
            fx_,
            fy_,
            pose.z - camera_height,
        )
        orr, occ = row[obstacle], col[obstacle]  # inside: `ensure` covered every point's range
        near = rho[obstacle] <= cfg.explore_range

        keep = ~np.isin(fr * w + fc, orr * w + occ)
        self._add(fr[keep], fc[keep], cfg.l_free)
        self._add(orr, occ, cfg.l_occ)
        self.explored[er, ec] = True
        self.explored[orr[near], occ[near]] = True
        return int(np.unique(orr * w + occ).size)

    def _fill_floor(
        self,
        floor: np.ndarray,
        rho: np.ndarray,
        height: np.ndarray,
        t: np.ndarray,
        along: np.ndarray,
        fx_: np.ndarray,
        fy_: np.ndarray,
        z0: float,
    ) -> None:
        """Floor height along each ray, between successive floor points (the first one being the
        robot's own feet) that differ by at most `step_height`: the floor is continuous there,
        seen or not (the camera never sees the floor right in front of the robot). Where they
        differ by more, the ray crossed a rim and the floor below stays unknown."""
        step = self.config.step_height
        r = np.where(floor, rho, np.inf)
        order = np.argsort(r, axis=0)
        rs = np.vstack([np.zeros((1, r.shape[1])), np.take_along_axis(r, order, axis=0)])
        hs = np.vstack([np.zeros((1, r.shape[1])), np.take_along_axis(height, order, axis=0)])
        n = np.isfinite(rs).sum(axis=0)  # (C,) floor points per column, feet included
        i = (rs[None, :, :] <= t[:, None, None]).sum(axis=1) - 1  # (T, C) bracketing pair
        i = np.clip(i, 0, np.maximum(n - 2, 0)[None, :])
        r0, r1 = np.take_along_axis(rs, i, axis=0), np.take_along_axis(rs, i + 1, axis=0)
        h0, h1 = np.take_along_axis(hs, i, axis=0), np.take_along_axis(hs, i + 1, axis=0)
        last = np.take_along_axis(rs, np.maximum(n - 1, 0)[None, :], axis=0)[0]
        tt = np.broadcast_to(t[:, None], along.shape)
        with np.errstate(invalid="ignore"):
            ok = along & (n >= 2)[None, :] & (tt <= last[None, :]) & (np.abs(h1 - h0) <= step)
            frac = np.clip((tt - r0) / np.maximum(r1 - r0, 1e-6), 0.0, 1.0)
        elev = np.where(ok, h0 + frac * (h1 - h0), np.nan)
        good = np.isfinite(elev) & (tt >= 0.0)
        rr, cc = self._cells(fx_[good], fy_[good])
        vals = (z0 + elev[good]).astype(np.float32)
        inb = np.isnan(self.elevation[rr, cc])  # a measured floor point wins over an interpolation
        self.elevation[rr[inb], cc[inb]] = vals[inb]

    def _cells(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World points -> in-bounds cell indices (points outside the grid are dropped)."""
        c = np.floor((x - self.origin[0]) / self.resolution).astype(np.int64)
        r = np.floor((y - self.origin[1]) / self.resolution).astype(np.int64)
        ok = (r >= 0) & (c >= 0) & (r < self.shape[0]) & (c < self.shape[1])
        return r[ok], c[ok]

    # --- numbers --------------------------------------------------------------------------
    def area(self, mask: np.ndarray) -> float:
        return float(mask.sum()) * self.resolution**2

    def explored_free_area(self) -> float:
        """Square metres of free floor the camera has looked at: the coverage measure."""
        return self.area(self.explored & self.free)

    # --- persistence ----------------------------------------------------------------------
    def metadata(self) -> dict[str, Any]:
        """Everything but the arrays: format, resolution, origin, shape, frame, config, meta."""
        return {
            "version": FORMAT_VERSION,
            "resolution": self.resolution,
            "origin": list(self.origin),
            "shape": list(self.shape),
            "frame": self.frame.as_dict(),
            "cells": "row = map y, col = map x; cell (0, 0) has its lower-left corner at origin",
            "config": asdict(self.config),
            "meta": self.meta,
        }

    def save(self, folder: str | Path) -> Path:
        """Write `map.npz` (arrays and metadata, one atomic replace) and `map.json` (the same
        metadata, for people and other tools) into a folder."""
        folder = Path(folder)
        folder.mkdir(parents=True, exist_ok=True)
        npz = folder / MAP_GRID
        meta = self.metadata()
        with atomic_open(npz) as f:
            np.savez_compressed(
                f,
                logodds=self.logodds,
                known=self.known,
                explored=self.explored,
                elevation=self.elevation,
                trajectory=np.asarray(self.trajectory, np.float32).reshape(-1, 2),
                meta=np.asarray(json.dumps(meta)),
            )
        atomic_write_json(folder / MAP_META, meta, indent=2)
        return npz

    @classmethod
    def load(cls, folder: str | Path) -> OccupancyGrid:
        """The map saved in a folder (a memory folder). InputError, one line, when there is none
        or it is damaged."""
        folder = Path(folder)
        meta_path, npz_path = folder / MAP_META, folder / MAP_GRID
        if not npz_path.is_file():
            raise InputError(
                f"{folder}: no {MAP_GRID} (build one: `ravenmem ingest` a recording with depth, "
                "`ravenmem map`, or `ravenmem explore` in a simulator)"
            )
        try:
            with np.load(npz_path) as z:
                arrays = {k: z[k] for k in z.files}
        except (OSError, ValueError, EOFError) as e:
            raise InputError(f"{npz_path}: unreadable map ({e})") from e
        where = npz_path
        try:
            if "meta" in arrays:
                meta = json.loads(str(arrays["meta"]))
            else:  # version 1: the metadata lived only in map.json
                where = meta_path
                meta = json.loads(meta_path.read_text())
            cfg = MapConfig.from_dict(meta["config"])
            origin = (float(meta["origin"][0]), float(meta["origin"][1]))
            shape = [int(v) for v in meta["shape"]]
            version = meta.get("version")
        except (OSError, ValueError, KeyError, TypeError, IndexError) as e:
            raise InputError(f"{where}: malformed map metadata ({e})") from e
        if version not in (1, FORMAT_VERSION):
            raise InputError(f"{where}: field 'version' is {version!r}, expected {FORMAT_VERSION}")
        grid = cls(cfg, origin)
        try:
            grid.logodds = arrays["logodds"].astype(np.float32)
            grid.known = arrays["known"].astype(bool)
            grid.explored = arrays["explored"].astype(bool)
        except KeyError as e:
            raise InputError(f"{npz_path}: map arrays incomplete (no {e})") from e
        el = arrays.get("elevation")
        grid.elevation = (
            el.astype(np.float32) if el is not None else np.full(grid.logodds.shape, np.nan, np.float32)
        )
        tr = arrays.get("trajectory")
        grid.trajectory = tr.astype(np.float32).reshape(-1, 2) if tr is not None else grid.trajectory
        grid.meta = dict(meta.get("meta") or {"kind": "explored"})
        if list(grid.shape) != shape or grid.known.shape != grid.logodds.shape:
            raise InputError(f"{where}: field 'shape' {shape} does not match the arrays {grid.shape}")
        return grid


def load_map(folder: str | Path) -> OccupancyGrid:
    """The map stored in a memory folder: `grid.free`, `grid.occupied`, `grid.unknown` (bool
    arrays, row = map y, col = map x), `grid.origin` (map x, y of cell (0, 0)'s lower-left
    corner), `grid.resolution` (metres per cell), `grid.trajectory` (N, 2), `grid.frame` (how
    map x, y relate to the memory's 3-D poses) and `grid.meta` (kind, sources)."""
    return OccupancyGrid.load(folder)


def read_map_image(path: Path, what: str = "map image") -> np.ndarray:
    """A map picture (a map_server PGM or PNG) as grey levels, (H, W) uint8, read within bounds
    as pictures are: at most `fsio.MAX_IMAGE` bytes (a FIFO or a device is refused before it is
    opened), at most MAX_MAP_CELLS pixels, checked from the header before anything is decoded
    (a 900 MP bomb is a few kilobytes). Every failure is one InputError naming the file."""
    data = read_bounded(path, MAX_IMAGE, what)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)  # bounded just below
            with Image.open(io.BytesIO(data)) as im:
                w, h = im.size
                if w * h > MAX_MAP_CELLS:
                    raise InputError(
                        f"{what} {path}: {w}x{h} pixels is more than the limit of {MAX_MAP_CELLS} for a map"
                    )
                return np.asarray(im.convert("L"), np.uint8)
    except InputError:
        raise
    except Image.DecompressionBombError:
        raise InputError(f"{what} {path}: more pixels than the limit of {MAX_MAP_CELLS} for a map") from None
    except UnidentifiedImageError:
        raise InputError(f"{what} {path}: not a picture Pillow can read (PGM or PNG)") from None
    except (OSError, ValueError, SyntaxError, EOFError) as e:  # a truncated or corrupt picture
        raise InputError(
            f"{what} {path}: unreadable ({str(e).splitlines()[0] if str(e) else type(e).__name__})"
        ) from None
