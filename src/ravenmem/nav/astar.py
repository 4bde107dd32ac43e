"""A* on an 8-connected grid, plus the grid helpers planning needs (line of sight, shortcutting,
a C-speed Dijkstra distance field for choosing among many goals at once).

Moves cost 1 (straight) and sqrt(2) (diagonal), in cells. A diagonal move is allowed only when
both straight neighbours are traversable, so a path never squeezes between two obstacles that
touch at a corner. The octile distance is exact on an empty grid, hence admissible and
consistent, so the first time the goal is popped its cost is optimal.
"""

from __future__ import annotations

import heapq
import math

import numpy as np
from scipy import ndimage, sparse
from scipy.sparse import csgraph

from .base import PLANNERS, Cell

SQRT2 = math.sqrt(2.0)
MOVES: tuple[tuple[int, int, float], ...] = (
    (-1, 0, 1.0),
    (1, 0, 1.0),
    (0, -1, 1.0),
    (0, 1, 1.0),
    (-1, -1, SQRT2),
    (-1, 1, SQRT2),
    (1, -1, SQRT2),
    (1, 1, SQRT2),
)


def octile(a: Cell, b: Cell) -> float:
    """Exact 8-connected distance on an empty grid (in cells)."""
    dr, dc = abs(a[0] - b[0]), abs(a[1] - b[1])
    return float(dr + dc) + (SQRT2 - 2.0) * min(dr, dc)


def _inside(shape: tuple[int, ...], c: Cell) -> bool:
    return 0 <= c[0] < shape[0] and 0 <= c[1] < shape[1]


def astar(traversable: np.ndarray, start: Cell, goal: Cell) -> tuple[list[Cell] | None, float, int]:
    """Shortest path from `start` to `goal` over True cells: (cells, cost in cells, expanded).

    Returns (None, inf, expanded) when the goal cannot be reached or either end is blocked.
    """
    trav = np.asarray(traversable, dtype=bool)
    h_, w_ = trav.shape
    if not (_inside(trav.shape, start) and _inside(trav.shape, goal)):
        return None, math.inf, 0
    if not (trav[start] and trav[goal]):
        return None, math.inf, 0
    flat = trav.ravel().tolist()
    n = h_ * w_
    si, gi = start[0] * w_ + start[1], goal[0] * w_ + goal[1]
    gr, gc = goal
    diag = SQRT2 - 2.0
    gscore = [math.inf] * n
    parent = [-1] * n
    closed = bytearray(n)
    gscore[si] = 0.0
    # entries: (f, -g, cell): among equal f, prefer the deeper node (fewer expansions)
    heap: list[tuple[float, float, int]] = [(octile(start, goal), 0.0, si)]
    expanded = 0
    while heap:
        _, neg_g, cur = heapq.heappop(heap)
        gcur = -neg_g
        if closed[cur]:
            continue
        closed[cur] = 1
        expanded += 1
        if cur == gi:
            break
        r, c = divmod(cur, w_)
        for dr, dc, cost in MOVES:
            nr, nc = r + dr, c + dc
            if nr < 0 or nc < 0 or nr >= h_ or nc >= w_:
                continue
            nb = nr * w_ + nc
            if closed[nb] or not flat[nb]:
                continue
            if dr and dc and not (flat[r * w_ + nc] and flat[nr * w_ + c]):
                continue
            ng = gcur + cost
            if ng < gscore[nb]:
                gscore[nb] = ng
                parent[nb] = cur
                ar, ac = abs(nr - gr), abs(nc - gc)
                heapq.heappush(heap, (ng + ar + ac + diag * min(ar, ac), -ng, nb))
    if not closed[gi]:
        return None, math.inf, expanded
    path = [gi]
    while path[-1] != si:
        path.append(parent[path[-1]])
    path.reverse()
    return [divmod(i, w_) for i in path], gscore[gi], expanded


def grid_graph(traversable: np.ndarray) -> sparse.csr_matrix:
    """The same 8-connected graph A* searches, as a sparse matrix over all cells (row-major)."""
    trav = np.asarray(traversable, dtype=bool)
    h_, w_ = trav.shape
    idx = np.arange(h_ * w_).reshape(h_, w_)
    src_all, dst_all, wt_all = [], [], []
    for dr, dc, cost in MOVES:
        rs = slice(max(0, -dr), h_ - max(0, dr))
        cs = slice(max(0, -dc), w_ - max(0, dc))
        rd = slice(max(0, dr), h_ + min(0, dr))
        cd = slice(max(0, dc), w_ + min(0, dc))
        ok = trav[rs, cs] & trav[rd, cd]
        if dr and dc:
            ok &= trav[rs, cd] & trav[rd, cs]
        src_all.append(idx[rs, cs][ok])
        dst_all.append(idx[rd, cd][ok])
        wt_all.append(np.full(int(ok.sum()), cost))
    src, dst, wt = np.concatenate(src_all), np.concatenate(dst_all), np.concatenate(wt_all)
    return sparse.csr_matrix((wt, (src, dst)), shape=(h_ * w_, h_ * w_))


def distance_field(traversable: np.ndarray, start: Cell) -> np.ndarray:
    """Path cost (cells) from `start` to every cell; inf where unreachable. Used to rank many
    goals (frontiers) with one search, and as the reference A* is tested against."""
    trav = np.asarray(traversable, dtype=bool)
    out = np.full(trav.shape, np.inf)
    if not (_inside(trav.shape, start) and trav[start]):
        return out
    rows, cols = np.nonzero(trav.any(axis=1))[0], np.nonzero(trav.any(axis=0))[0]
    r0, r1, c0, c1 = rows[0], rows[-1] + 1, cols[0], cols[-1] + 1  # search only the bounding box
    sub = trav[r0:r1, c0:c1]
    d = csgraph.dijkstra(
        grid_graph(sub), directed=True, indices=(start[0] - r0) * sub.shape[1] + start[1] - c0
    )
    out[r0:r1, c0:c1] = np.asarray(d).reshape(sub.shape)
    return out


def reachable(traversable: np.ndarray, start: Cell) -> np.ndarray:
    """Cells reachable from `start`. With corner cutting forbidden, a diagonal move can always
    be replaced by two straight ones, so this is the 4-connected component (fast, in C)."""
    trav = np.asarray(traversable, dtype=bool)
    if not (_inside(trav.shape, start) and trav[start]):
        return np.zeros(trav.shape, bool)
    labels, _ = ndimage.label(trav)
    return np.asarray(labels == labels[start])


def line_cells(a: Cell, b: Cell) -> tuple[np.ndarray, np.ndarray]:
    """Cells a straight segment from a to b passes (sampled at a quarter cell, both ends kept)."""
    n = int(max(abs(b[0] - a[0]), abs(b[1] - a[1])) * 4) + 1
    rr = np.rint(np.linspace(a[0], b[0], n + 1)).astype(int)
    cc = np.rint(np.linspace(a[1], b[1], n + 1)).astype(int)
    return rr, cc


def line_of_sight(mask: np.ndarray, a: Cell, b: Cell) -> bool:
    """True when every cell on the segment a-b is True in `mask`."""
    rr, cc = line_cells(a, b)
    if rr.min() < 0 or cc.min() < 0 or rr.max() >= mask.shape[0] or cc.max() >= mask.shape[1]:
        return False
    return bool(mask[rr, cc].all())


def simplify(cells: list[Cell], traversable: np.ndarray) -> list[Cell]:
    """Drop intermediate cells while the straight line stays on traversable cells (string
    pulling), so the controller drives long straight legs instead of a staircase."""
    if len(cells) <= 2:
        return list(cells)
    out = [cells[0]]
    i = 0
    while i < len(cells) - 1:
        j = i + 1
        while j + 1 < len(cells) and line_of_sight(traversable, cells[i], cells[j + 1]):
            j += 1
        out.append(cells[j])
        i = j
    return out


class AStarPlanner:
    """The built-in planner: hand-written A* (octile heuristic) over the traversability grid."""

    name = "astar"

    def plan(self, traversable: np.ndarray, start: Cell, goal: Cell) -> tuple[list[Cell] | None, float, int]:
        return astar(traversable, start, goal)


@PLANNERS.register("astar")
def _make_astar(spec: str = "") -> AStarPlanner:
    return AStarPlanner()
