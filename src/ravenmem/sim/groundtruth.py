"""Ground truth from a simulator's wall segments: the floor the robot could reach, used to
state exploration coverage as a fraction and to check the mapper (never used for planning)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np
from scipy import ndimage


class MapLike(Protocol):
    """What coverage needs from a map (an `OccupancyGrid` has it): the simulator sits below
    the navigation floor, so it names the shape, not the class."""

    origin: tuple[float, float]
    resolution: float

    @property
    def explored(self) -> np.ndarray: ...

    @property
    def free(self) -> np.ndarray: ...


@dataclass
class FloorTruth:
    """Boolean mask of reachable floor cells; row = y, col = x, `origin` = world (x, y) of cell (0, 0)."""

    mask: np.ndarray
    walls: np.ndarray
    origin: tuple[float, float]
    resolution: float
    _edt: np.ndarray | None = field(default=None, repr=False)

    @property
    def area(self) -> float:
        return float(self.mask.sum()) * self.resolution**2

    def cells(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        r = np.floor((np.asarray(y) - self.origin[1]) / self.resolution).astype(np.int64)
        c = np.floor((np.asarray(x) - self.origin[0]) / self.resolution).astype(np.int64)
        ok = (r >= 0) & (c >= 0) & (r < self.mask.shape[0]) & (c < self.mask.shape[1])
        return r, c, ok

    def distance(self, x: float, y: float) -> float:
        """Metres from (x, y) to the nearest reachable floor cell (0 on it; inf outside the map)."""
        if not self.mask.any():
            return float("inf")
        if self._edt is None:
            self._edt = ndimage.distance_transform_edt(~self.mask) * self.resolution
        r, c, ok = self.cells(np.asarray([x]), np.asarray([y]))
        return float(self._edt[r[0], c[0]]) if ok[0] else float("inf")

    def coverage(self, grid: MapLike) -> float:
        """Fraction of the reachable floor that the map has explored as free."""
        rr, cc = np.nonzero(grid.explored & grid.free)
        if rr.size == 0 or not self.mask.any():
            return 0.0
        wx = grid.origin[0] + (cc + 0.5) * grid.resolution
        wy = grid.origin[1] + (rr + 0.5) * grid.resolution
        r, c, ok = self.cells(wx, wy)
        hit = np.zeros_like(self.mask)
        hit[r[ok], c[ok]] = True
        return float((hit & self.mask).sum()) / float(self.mask.sum())


def rasterize_segments(
    segments: np.ndarray, origin: tuple[float, float], shape: tuple[int, int], resolution: float
) -> np.ndarray:
    """Cells crossed by the segments (sampled every third of a cell: 8-connected, leak-proof
    for a 4-connected flood fill)."""
    walls = np.zeros(shape, bool)
    step = resolution / 3.0
    for x1, y1, x2, y2 in np.asarray(segments, np.float64).reshape(-1, 4):
        n = int(math.ceil(math.hypot(x2 - x1, y2 - y1) / step)) + 1
        t = np.linspace(0.0, 1.0, n)
        c = np.floor((x1 + t * (x2 - x1) - origin[0]) / resolution).astype(np.int64)
        r = np.floor((y1 + t * (y2 - y1) - origin[1]) / resolution).astype(np.int64)
        ok = (r >= 0) & (c >= 0) & (r < shape[0]) & (c < shape[1])
        walls[r[ok], c[ok]] = True
    return walls


def reachable_floor(
    segments: np.ndarray, start: tuple[float, float], resolution: float = 0.25, margin: float = 1.0
) -> FloorTruth:
    """Flood-fill the floor from `start` without crossing a wall segment."""
    seg = np.asarray(segments, np.float64).reshape(-1, 4)
    xs = np.concatenate([seg[:, 0], seg[:, 2], [start[0]]])
    ys = np.concatenate([seg[:, 1], seg[:, 3], [start[1]]])
    origin = (float(xs.min()) - margin, float(ys.min()) - margin)
    shape = (
        int(math.ceil((ys.max() - origin[1] + margin) / resolution)) + 1,
        int(math.ceil((xs.max() - origin[0] + margin) / resolution)) + 1,
    )
    walls = rasterize_segments(seg, origin, shape, resolution)
    labels, _ = ndimage.label(~walls)
    r = int(math.floor((start[1] - origin[1]) / resolution))
    c = int(math.floor((start[0] - origin[0]) / resolution))
    mask = labels == labels[r, c] if labels[r, c] else np.zeros(shape, bool)
    return FloorTruth(mask=mask, walls=walls, origin=origin, resolution=resolution)
