"""World-frame planning on an occupancy grid: start/goal to cells, goal snapping, A*, waypoints."""

from __future__ import annotations

import math

import numpy as np
from scipy import ndimage

from .astar import line_of_sight, reachable, simplify
from .base import Cell, Planner, PlanResult, create_planner
from .grid import OccupancyGrid


def nearest_cell(mask: np.ndarray, cell: Cell, max_cells: int) -> Cell | None:
    """Nearest True cell of `mask` within `max_cells` (Euclidean), or None."""
    h, w = mask.shape
    r0, r1 = max(0, cell[0] - max_cells), min(h, cell[0] + max_cells + 1)
    c0, c1 = max(0, cell[1] - max_cells), min(w, cell[1] + max_cells + 1)
    if r0 >= r1 or c0 >= c1:
        return None
    rr, cc = np.nonzero(mask[r0:r1, c0:c1])
    if rr.size == 0:
        return None
    d2 = (rr + r0 - cell[0]) ** 2 + (cc + c0 - cell[1]) ** 2
    k = int(np.argmin(d2))
    if d2[k] > max_cells * max_cells:
        return None
    return (int(rr[k] + r0), int(cc[k] + c0))


def snap_goal(
    grid: OccupancyGrid, reachable: np.ndarray, goal: Cell, max_cells: int, body_cells: int = 2
) -> tuple[Cell | None, bool]:
    """Nearest reachable cell that can see `goal` (line of sight through cells not occupied; when
    the goal is itself occupied, its own blob within `body_cells` does not block the view). Returns (cell, saw_goal); when no
    reachable cell within `max_cells` sees the goal, the nearest reachable one with False."""
    h, w = reachable.shape
    r0, r1 = max(0, goal[0] - max_cells), min(h, goal[0] + max_cells + 1)
    c0, c1 = max(0, goal[1] - max_cells), min(w, goal[1] + max_cells + 1)
    if r0 >= r1 or c0 >= c1:
        return None, False
    rr, cc = np.nonzero(reachable[r0:r1, c0:c1])
    if rr.size == 0:
        return None, False
    rr, cc = rr + r0, cc + c0
    d2 = (rr - goal[0]) ** 2 + (cc - goal[1]) ** 2
    order = np.argsort(d2, kind="stable")
    order = order[d2[order] <= max_cells * max_cells]
    if order.size == 0:
        return None, False
    occ = grid.occupied
    see = ~occ
    gr, gc = goal
    inside = 0 <= gr < h and 0 <= gc < w
    if inside and occ[goal]:
        # The goal is an obstacle itself (the object asked for): its own blob, near the goal,
        # does not hide it; other obstacles do.
        br0, br1 = max(0, gr - body_cells), min(h, gr + body_cells + 1)
        bc0, bc1 = max(0, gc - body_cells), min(w, gc + body_cells + 1)
        lab, _ = ndimage.label(occ[br0:br1, bc0:bc1], structure=np.ones((3, 3), bool))
        see[br0:br1, bc0:bc1] |= lab == lab[gr - br0, gc - bc0]
    for k in order[:400]:
        cand = (int(rr[k]), int(cc[k]))
        if inside and line_of_sight(see, cand, goal):
            return cand, True
    k = int(order[0])
    return (int(rr[k]), int(cc[k])), False


def start_near(
    grid: OccupancyGrid,
    start: tuple[float, float],
    goal: tuple[float, float],
    robot_radius: float,
    snap_radius: float = 4.0,
) -> tuple[float, float] | None:
    """A start the robot can plan from, nearest to `start`: the nearest free cell (for a body of
    `robot_radius`) of the largest free region that reaches within `snap_radius` of `goal` (the
    largest region of all when none does). None when that is where `start` already is, or the
    map has no free space. For a last pose that lies in a pocket the map closes off (a ledge
    the robot dropped from, a doorway mapped shut, noise around the robot's own body)."""
    trav = grid.traversable(robot_radius)
    labels, n = ndimage.label(trav)
    if n == 0:
        return None
    sizes = np.bincount(labels.ravel())
    sizes[0] = 0
    g = grid.world_to_cell(*goal)
    k = int(math.ceil(snap_radius / grid.resolution))
    h, w = trav.shape
    r0, r1, c0, c1 = max(0, g[0] - k), min(h, g[0] + k + 1), max(0, g[1] - k), min(w, g[1] + k + 1)
    near = np.unique(labels[r0:r1, c0:c1]) if r0 < r1 and c0 < c1 else np.zeros(0, np.int64)
    near = near[near > 0]
    region = int(near[np.argmax(sizes[near])]) if near.size else int(np.argmax(sizes))
    s = grid.world_to_cell(*start)
    if grid.contains(s) and labels[s] == region:
        return None
    cell = nearest_cell(labels == region, s, max(h, w))
    return None if cell is None else grid.cell_to_world(cell)


def plan_path(
    grid: OccupancyGrid,
    start: tuple[float, float],
    goal: tuple[float, float],
    robot_radius: float,
    planner: Planner | None = None,
    snap_radius: float = 4.0,
) -> PlanResult:
    """Plan from world `start` to world `goal` over free space inflated by `robot_radius`.

    A goal inside an obstacle or unknown space is moved to the nearest reachable free cell that
    can see it (within `snap_radius` metres); a goal with no reachable cell nearby gives
    `ok=False` and a reason, never an exception.
    """
    planner = planner or create_planner("astar")
    res = grid.resolution
    result = PlanResult(ok=False, requested=goal)
    if grid.shape[0] == 0:
        result.reason = "the map is empty"
        return result
    trav = grid.traversable(robot_radius)
    s = grid.world_to_cell(*start)
    if not (grid.contains(s) and trav[s]):
        rescued = nearest_cell(trav, s, max(2, int(math.ceil(2 * robot_radius / res))))
        if rescued is None:
            result.reason = f"start ({start[0]:.2f}, {start[1]:.2f}) is not in known free space"
            return result
        s = rescued
    reach = reachable(trav, s)
    g = grid.world_to_cell(*goal)
    if grid.contains(g) and reach[g]:
        g_used, saw = g, True
    else:
        cand, saw = snap_goal(grid, reach, g, int(math.ceil(snap_radius / res)))
        if cand is None:
            result.reason = (
                f"goal ({goal[0]:.2f}, {goal[1]:.2f}) is unreachable: no reachable free cell "
                f"within {snap_radius:.1f} m"
            )
            return result
        g_used = cand
    cells, cost, expanded = planner.plan(trav, s, g_used)
    result.expanded = expanded
    if cells is None:
        result.reason = f"goal ({goal[0]:.2f}, {goal[1]:.2f}) is unreachable for planner {planner.name}"
        return result
    pts = [grid.cell_to_world(c) for c in simplify(cells, trav)]
    pts[0] = (float(start[0]), float(start[1]))
    result.ok = True
    result.cells = cells
    result.waypoints = pts
    result.length_m = float(sum(math.dist(a, b) for a, b in zip(pts, pts[1:])))
    result.goal = grid.cell_to_world(g_used)
    result.snapped = g_used != g
    if result.snapped and not saw:
        result.reason = "no reachable cell sees the goal; using the nearest reachable cell"
    return result
