"""Frontiers: free cells that touch unknown space, grouped into clusters and ranked by the
path cost from the robot, so exploration always heads for the nearest place that would
reveal something new and that the robot can actually reach."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from .astar import distance_field, line_of_sight
from .grid import OccupancyGrid
from .planning import nearest_cell

_CROSS = ndimage.generate_binary_structure(2, 1)
_SQUARE = np.ones((3, 3), bool)


@dataclass
class Frontier:
    """One cluster of frontier cells; `target` is the reachable cell the robot drives to."""

    cells: np.ndarray  # (k, 2) rows, cols
    centroid: tuple[float, float]  # world metres
    target: tuple[float, float]  # world metres
    target_cell: tuple[int, int]
    cost_m: float  # path length from the robot to the target

    @property
    def size(self) -> int:
        return int(self.cells.shape[0])


def frontier_mask(free: np.ndarray, unknown: np.ndarray) -> np.ndarray:
    """Free cells with an unknown 4-neighbour. Cells on the grid border count as bordering
    the unknown world outside it."""
    unk = np.pad(unknown, 1, constant_values=True)
    near_unknown = ndimage.binary_dilation(unk, structure=_CROSS)[1:-1, 1:-1]
    return free & near_unknown


def cluster_frontiers(mask: np.ndarray, min_size: int = 1) -> list[np.ndarray]:
    """8-connected clusters of frontier cells with at least `min_size` cells, as (k, 2) arrays."""
    labels, n = ndimage.label(mask, structure=_SQUARE)
    if n == 0:
        return []
    rr, cc = np.nonzero(labels)
    lab = labels[rr, cc]
    order = np.argsort(lab, kind="stable")
    splits = np.flatnonzero(np.diff(lab[order])) + 1
    groups = np.split(np.stack([rr[order], cc[order]], axis=1), splits)
    return [g for g in groups if g.shape[0] >= min_size]


def find_frontiers(
    grid: OccupancyGrid,
    robot: tuple[float, float],
    robot_radius: float,
    min_size: int = 4,
    reach: float | None = None,
    blacklist: list[tuple[float, float]] | None = None,
    blacklist_radius: float = 1.0,
) -> list[Frontier]:
    """Reachable frontier clusters, nearest (by path length) first.

    A cluster is reachable when some traversable cell within `reach` metres of one of its cells
    (default: robot radius + 0.5 m, close enough to see past it) is connected to the robot.
    Clusters near a `blacklist` point (a frontier the robot went to and could not clear) are
    skipped.
    """
    res = grid.resolution
    if grid.shape[0] == 0:
        return []
    reach = robot_radius + 0.5 if reach is None else reach
    trav = grid.traversable(robot_radius)
    s = grid.world_to_cell(*robot)
    if not (grid.contains(s) and trav[s]):
        rescued = nearest_cell(trav, s, max(2, int(math.ceil(2 * robot_radius / res))))
        if rescued is None:
            return []
        s = rescued
    dist = distance_field(trav, s)
    mask = frontier_mask(grid.free, grid.unknown)
    if blacklist:
        rr, cc = np.nonzero(mask)
        if rr.size:
            wx = grid.origin[0] + (cc + 0.5) * res
            wy = grid.origin[1] + (rr + 0.5) * res
            bad = np.zeros(rr.size, bool)
            for bx, by in blacklist:
                bad |= (wx - bx) ** 2 + (wy - by) ** 2 <= blacklist_radius**2
            mask[rr[bad], cc[bad]] = False
    clusters = cluster_frontiers(mask, min_size)
    if not clusters:
        return []
    labels = np.zeros(grid.shape, np.int32)
    for i, cl in enumerate(clusters, start=1):
        labels[cl[:, 0], cl[:, 1]] = i
    # For every cell, the nearest frontier cell (and its cluster) and how far it is.
    edt, (ir, ic) = ndimage.distance_transform_edt(labels == 0, return_indices=True)
    ok = np.isfinite(dist) & (edt * res <= reach)
    rr, cc = np.nonzero(ok)
    out: list[Frontier] = []
    if rr.size == 0:
        return out
    fr_, fc_ = ir[rr, cc], ic[rr, cc]
    lab = labels[fr_, fc_]
    cost = dist[rr, cc]
    see = ~grid.occupied
    best: dict[int, int] = {}
    tries: dict[int, int] = {}
    for k in np.argsort(cost, kind="stable"):
        li = int(lab[k])
        if li in best or tries.get(li, 0) >= 40:
            continue
        tries[li] = tries.get(li, 0) + 1
        # the frontier must be in view from the approach cell, not behind a thin wall
        if line_of_sight(see, (int(rr[k]), int(cc[k])), (int(fr_[k]), int(fc_[k]))):
            best[li] = int(k)
    for li, k in best.items():
        cl = clusters[li - 1]
        cen = cl.mean(axis=0)
        cell = (int(rr[k]), int(cc[k]))
        out.append(
            Frontier(
                cells=cl,
                centroid=grid.cell_to_world((int(round(cen[0])), int(round(cen[1])))),
                target=grid.cell_to_world(cell),
                target_cell=cell,
                cost_m=float(cost[k]) * res,
            )
        )
    out.sort(key=lambda f: f.cost_m)
    return out
