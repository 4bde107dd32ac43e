"""Align two memories of one place: the rigid transform from memory A's map into memory B's,
estimated from the places both saw, or given; and re-anchoring A into B's map with it.

Two sessions of a robot whose SLAM (or odometry) started in different places describe the same
rooms in different coordinates. The transform between them, a rotation about z and a shift
(REP 103), is found in three steps:

1. image matches: each of up to `max_queries` of A's memories (spread over its time span) is
   searched in B by its embedding; a match is kept when it is clearly the best (its score beats
   the second best by `margin`) and mutual (B's memory finds A's back). Views that look like
   many others (a bare wall) fail the test and are left out;
2. a robust rigid fit of the matched poses (RANSAC): every match proposes the transform that
   puts A's camera onto B's (position and heading); the one most matches agree with (within
   `inlier_m` metres and `inlier_deg` degrees) wins, and a least-squares fit over its inliers
   (2-D Kabsch) refines it;
3. when both memories have occupancy maps on z-up floors, the maps' obstacles are fitted onto
   each other from there (point-to-point ICP with a shrinking match distance): cameras that saw
   the same thing from a metre apart give a transform good to about that; walls give centimetres.

`apply` re-anchors A: its poses go through the transform (`Memory.reanchor`, journalled, from
the poses first stored, nothing re-embedded), its map is resampled into B's frame from the map
as first built (kept in `anchor/`), and A takes B's map identity, so answers from A are goals
on B's map (`nav.goals.goal_for` refuses answers of a map it was never aligned to). `undo` puts
both back. A crash between the poses and the map leaves them out of step; `goal_for` then
refuses to plan and says to run `ravenmem align --apply` again (which redoes both).
"""

from __future__ import annotations

import math
import shutil
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.spatial import cKDTree

from ..errors import InputError
from ..memory import Memory
from ..memory.anchor import Transform
from ..memory.folder import ANCHOR, MAP_GRID, MAP_META
from .grid import OccupancyGrid


@dataclass(frozen=True)
class AlignConfig:
    """How the transform is estimated (see the module docstring)."""

    max_queries: int = 600
    min_score: float = 0.5
    margin: float = 0.002
    inlier_m: float = 1.5
    inlier_deg: float = 30.0
    min_inliers: int = 4
    icp: bool = True
    seed: int = 0


@dataclass
class Alignment:
    """A transform from memory A's map into memory B's, and how it was found."""

    transform: Transform
    from_map: str
    to_map: str
    method: str  # images | images+maps | given
    matches: int = 0
    inliers: int = 0
    residual_m: float | None = None  # RMS position error of the inliers after the fit
    map_fit: dict[str, Any] | None = None
    notes: list[str] = field(default_factory=list)

    def as_dict(self) -> dict[str, Any]:
        t = self.transform
        return {
            "transform": {"x": t.x, "y": t.y, "z": t.z, "yaw": t.yaw, "yaw_deg": math.degrees(t.yaw)},
            "from_map": self.from_map,
            "to_map": self.to_map,
            "method": self.method,
            "matches": self.matches,
            "inliers": self.inliers,
            "residual_m": self.residual_m,
            "map_fit": self.map_fit,
            "notes": self.notes,
        }


def estimate(a: Memory, b: Memory, cfg: AlignConfig | None = None) -> Alignment:
    """The transform from A's map into B's (see the module docstring); InputError, one line,
    when the memories cannot be compared or too few places match."""
    cfg = cfg or AlignConfig()
    if (a.manifest.embedder, a.dim) != (b.manifest.embedder, b.dim):
        raise InputError(
            f"{a.path} and {b.path} were built with different embedders ({a.manifest.embedder!r}, "
            f"{b.manifest.embedder!r}): their pictures cannot be compared; give --transform"
        )
    if a.count() == 0 or b.count() == 0:
        raise InputError("both memories must hold memories to be aligned")
    pa, pb = _matches(a, b, cfg)
    out = Alignment(Transform(), a.map_id, b.map_id, "images", matches=len(pa))
    if len(pa) < cfg.min_inliers:
        raise InputError(
            f"only {len(pa)} places of {a.path} clearly match places of {b.path} (need {cfg.min_inliers}): "
            "no transform can be estimated from them; give one with --transform x,y,z,yaw"
        )
    t, inliers = _ransac(pa, pb, cfg)
    if inliers.sum() < cfg.min_inliers:
        raise InputError(
            f"the {len(pa)} matched places do not agree on one transform (best: {int(inliers.sum())} "
            f"agree, need {cfg.min_inliers}); give one with --transform x,y,z,yaw"
        )
    out.transform, out.inliers = t, int(inliers.sum())
    out.residual_m = _rms(t, pa[inliers], pb[inliers])
    if cfg.icp:
        _refine_with_maps(a, b, out, cfg)
    # found between A's poses as they are now; `reanchor` starts from the poses as first stored
    out.transform = a.current_transform().then(out.transform)
    return out


def _matches(a: Memory, b: Memory, cfg: AlignConfig) -> tuple[np.ndarray, np.ndarray]:
    """Matched poses (N, 4: x, y, z, yaw) of A and of B: clear, mutual best image matches."""
    ids = a.store.select()
    if len(ids) > cfg.max_queries:
        ids = ids[np.linspace(0, len(ids) - 1, cfg.max_queries).round().astype(int)]
    recs = a.store.get(ids.tolist(), with_embeddings=True)
    rows_a, rows_b = [], []
    for rec in recs:
        assert rec.embedding is not None
        hits = b.store.search_vector(rec.embedding, 2)
        if not hits or hits[0][1] < cfg.min_score:
            continue
        if len(hits) > 1 and hits[0][1] - hits[1][1] < cfg.margin:
            continue  # a view like many others: no place to tell by it
        (other,) = b.store.get([hits[0][0]], with_embeddings=True)
        assert other.embedding is not None
        back = a.store.search_vector(other.embedding, 1)
        if not back or back[0][0] != rec.id:
            continue
        rows_a.append((*rec.pose.xyz, rec.pose.yaw))
        rows_b.append((*other.pose.xyz, other.pose.yaw))
    return np.asarray(rows_a, np.float64).reshape(-1, 4), np.asarray(rows_b, np.float64).reshape(-1, 4)


def _wrap(a: np.ndarray | float) -> Any:
    return (np.asarray(a) + np.pi) % (2 * np.pi) - np.pi


def _apply(t: Transform, p: np.ndarray) -> np.ndarray:
    c, s = math.cos(t.yaw), math.sin(t.yaw)
    x, y = p[:, 0], p[:, 1]
    return np.stack([c * x - s * y + t.x, s * x + c * y + t.y, p[:, 2] + t.z, _wrap(p[:, 3] + t.yaw)], 1)


def _agree(t: Transform, pa: np.ndarray, pb: np.ndarray, cfg: AlignConfig) -> np.ndarray:
    q = _apply(t, pa)
    near = np.hypot(q[:, 0] - pb[:, 0], q[:, 1] - pb[:, 1]) <= cfg.inlier_m
    return near & (np.abs(_wrap(q[:, 3] - pb[:, 3])) <= math.radians(cfg.inlier_deg))


def _ransac(pa: np.ndarray, pb: np.ndarray, cfg: AlignConfig) -> tuple[Transform, np.ndarray]:
    """The transform most matches agree with (each match proposes one), refit on its inliers."""
    best = np.zeros(len(pa), bool)
    best_t = Transform()
    for i in range(len(pa)):
        yaw = float(_wrap(pb[i, 3] - pa[i, 3]))
        c, s = math.cos(yaw), math.sin(yaw)
        t = Transform(
            float(pb[i, 0] - (c * pa[i, 0] - s * pa[i, 1])),
            float(pb[i, 1] - (s * pa[i, 0] + c * pa[i, 1])),
            float(pb[i, 2] - pa[i, 2]),
            yaw,
        )
        ok = _agree(t, pa, pb, cfg)
        if ok.sum() > best.sum():
            best, best_t = ok, t
    for _ in range(5):  # refit on the inliers, then take the inliers of the refit
        if best.sum() < 2:
            break
        t = _fit(pa[best], pb[best])
        ok = _agree(t, pa, pb, cfg)
        if ok.sum() < best.sum():
            break
        best, best_t = ok, t
    return best_t, best


def _fit(pa: np.ndarray, pb: np.ndarray) -> Transform:
    """Least-squares rigid fit in the plane (2-D Kabsch) of A's positions onto B's, with the
    headings' mean difference joining the positions when they are few (two cameras at one
    place still say how the maps are turned)."""
    ca, cb = pa[:, :2].mean(0), pb[:, :2].mean(0)
    xa, xb = pa[:, :2] - ca, pb[:, :2] - cb
    spread = float((xa**2).sum())
    dyaw = _wrap(pb[:, 3] - pa[:, 3])
    heading = math.atan2(float(np.sin(dyaw).sum()), float(np.cos(dyaw).sum()))
    if spread < 1.0:  # positions within a metre of each other: the headings say the rotation
        yaw = heading
    else:
        h = xa.T @ xb
        yaw = math.atan2(h[0, 1] - h[1, 0], h[0, 0] + h[1, 1])
    c, s = math.cos(yaw), math.sin(yaw)
    tx, ty = cb - np.array([c * ca[0] - s * ca[1], s * ca[0] + c * ca[1]])
    return Transform(float(tx), float(ty), float(np.median(pb[:, 2] - pa[:, 2])), float(yaw))


def _rms(t: Transform, pa: np.ndarray, pb: np.ndarray) -> float:
    q = _apply(t, pa)
    return float(np.sqrt(np.mean((q[:, 0] - pb[:, 0]) ** 2 + (q[:, 1] - pb[:, 1]) ** 2)))


def _obstacles(mem: Memory) -> np.ndarray | None:
    """Map x, y of every occupied cell of a memory's map, in the frame its poses are in now
    (None: no map, or not z-up)."""
    try:
        grid = OccupancyGrid.load(_original_map_folder(mem))
    except InputError:
        return None
    if not grid.frame.is_world_xy:
        return None
    rows, cols = np.nonzero(grid.occupied)
    if rows.size < 20:
        return None
    x = grid.origin[0] + (cols + 0.5) * grid.resolution
    y = grid.origin[1] + (rows + 0.5) * grid.resolution
    pts = np.c_[x, y, np.zeros((len(x), 2))]
    return _apply(mem.current_transform(), pts)[:, :2]  # the map as first built, moved as the poses


def _refine_with_maps(a: Memory, b: Memory, out: Alignment, cfg: AlignConfig) -> None:
    """Fit A's obstacles onto B's from the image estimate (ICP); kept when most fit and it stays
    near the image estimate, else the image estimate stands (with a note)."""
    src, dst = _obstacles(a), _obstacles(b)
    if src is None or dst is None:
        out.notes.append("no z-up occupancy maps in both memories: the transform is the image fit alone")
        return
    tree = cKDTree(dst)
    t = out.transform
    start = t
    frac = 0.0
    rms = math.inf
    for limit in (1.0, 0.6, 0.4, 0.3, 0.2, 0.2, 0.15, 0.15):
        for _ in range(6):
            q = _apply(t, np.c_[src, np.zeros((len(src), 2))])[:, :2]
            d, j = tree.query(q, distance_upper_bound=limit)
            ok = np.isfinite(d)
            if ok.sum() < 20:
                break
            pa = np.c_[src[ok], np.zeros((int(ok.sum()), 2))]
            pb = np.c_[dst[j[ok]], np.zeros((int(ok.sum()), 2))]
            step = _fit(pa, pb)
            t = Transform(step.x, step.y, t.z, step.yaw)
            frac, rms = float(ok.mean()), float(np.sqrt(np.mean(d[ok] ** 2)))
    moved = math.hypot(t.x - start.x, t.y - start.y)
    turned = abs(float(_wrap(t.yaw - start.yaw)))
    out.map_fit = {"fitted": round(frac, 3), "rms_m": round(rms, 3), "moved_m": round(moved, 3)}
    if frac < 0.5 or moved > 2 * cfg.inlier_m or turned > math.radians(cfg.inlier_deg):
        out.notes.append(
            f"the maps did not fit from the image estimate ({frac:.0%} of A's obstacles within 0.15 m "
            f"of B's): the transform is the image fit alone"
        )
        return
    out.transform, out.method = t, "images+maps"


# ------------------------------------------------------------------------- applying


def _original_map_folder(mem: Memory) -> Any:
    kept = mem.path / ANCHOR
    return kept if (kept / MAP_GRID).is_file() else mem.path


def apply(a: Memory, t: Transform, map_id: str, frame_id: str) -> dict[str, Any]:
    """Re-anchor memory A into map `map_id` through `t` (from A's poses as first stored): its
    poses, then its map (resampled from the map as first built). Returns what moved."""
    moved = a.reanchor(t, map_id, frame_id)
    return {"memories": moved, "map": _move_map(a, t)}


def undo(a: Memory) -> dict[str, Any]:
    """Put A's poses and map back where they were first stored and built."""
    moved = a.unanchor()
    return {"memories": moved, "map": _move_map(a, None)}


def _move_map(a: Memory, t: Transform | None) -> str:
    """A's map in its new frame (`t`), or back as first built (None); what was done, in words."""
    if not (a.path / MAP_GRID).is_file() and not (a.path / ANCHOR / MAP_GRID).is_file():
        return "no map"
    w = a.writer()
    with w.change():
        kept = a.path / ANCHOR
        if not (kept / MAP_GRID).is_file():  # the map as first built, kept once
            original = OccupancyGrid.load(a.path)
            if t is not None and not original.frame.is_world_xy:
                raise InputError(
                    f"{a.path}: its map's floor is not the world's x, y (a hand-held recording): it "
                    "cannot be turned about z; the poses were re-anchored, the map was not"
                )
            original.save(kept)
        original = OccupancyGrid.load(kept)
        if t is None:
            original.save(a.path)
            for name in (MAP_GRID, MAP_META):
                (kept / name).unlink(missing_ok=True)
            if kept.is_dir() and not any(kept.iterdir()):
                shutil.rmtree(kept, ignore_errors=True)
            return "restored as first built"
        moved = transform_grid(original, t)
        moved.save(a.path)
        return f"resampled into the new frame ({moved.shape[1]} x {moved.shape[0]} cells)"


def transform_grid(grid: OccupancyGrid, t: Transform) -> OccupancyGrid:
    """A copy of a z-up grid with everything turned and shifted by `t` (nearest cell)."""
    res = grid.resolution
    h, w = grid.shape
    x0, y0 = grid.origin
    corners = np.array([[x0, y0], [x0 + w * res, y0], [x0, y0 + h * res], [x0 + w * res, y0 + h * res]])
    moved = _apply(t, np.c_[corners, np.zeros((4, 2))])[:, :2]
    lo, hi = moved.min(0), moved.max(0)
    nw, nh = int(math.ceil((hi[0] - lo[0]) / res)) + 1, int(math.ceil((hi[1] - lo[1]) / res)) + 1
    out = OccupancyGrid(grid.config, (float(lo[0]), float(lo[1])), (nh, nw))
    rr, cc = np.mgrid[0:nh, 0:nw]
    cx, cy = lo[0] + (cc + 0.5) * res, lo[1] + (rr + 0.5) * res
    back = _apply(t.inverse(), np.stack([cx.ravel(), cy.ravel(), np.zeros(cx.size), np.zeros(cx.size)], 1))
    sc = np.floor((back[:, 0] - x0) / res).astype(int)
    sr = np.floor((back[:, 1] - y0) / res).astype(int)
    inside = (sr >= 0) & (sr < h) & (sc >= 0) & (sc < w)
    flat = np.flatnonzero(inside)
    for name in ("logodds", "known", "explored", "elevation"):
        src = getattr(grid, name)
        dst = getattr(out, name).reshape(-1)
        dst[flat] = src[sr[inside], sc[inside]]
        setattr(out, name, dst.reshape(nh, nw))
    out.elevation = out.elevation + np.float32(t.z)
    traj = np.asarray(grid.trajectory, np.float64).reshape(-1, 2)
    out.trajectory = _apply(t, np.c_[traj, np.zeros((len(traj), 2))])[:, :2].astype(np.float32)
    out.meta = dict(grid.meta) | {"anchor": t.as_list()}
    out.touch()
    return out
