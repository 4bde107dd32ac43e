"""Poses from a TF tree: parent -> child through any chain of transforms.

Two ways, for two kinds of input. `TfTree` reads a whole recording (ros/bag.py) and answers a
pose track: each (parent, child) edge is a time series of transforms (or one static transform
from /tf_static), and the pose of `child` in `parent` is found through their common ancestor,
T_parent_child = inv(T_anc_parent) * T_anc_child, with every moving edge interpolated at the
union of the moving edges' sample times (within the span they all cover). `TfBuffer` serves a
live stream, the rclpy node's (ros/intake.py) and the Zenoh link's (ros/link.py) alike: a
bounded window of recent samples per frame, each lookup one pose at one time (see below).
"""

from __future__ import annotations

import bisect
import math
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation

from ..errors import InputError
from ..ingest.poses import PoseTrack


@dataclass
class Edge:
    t: list[float] = field(default_factory=list)
    xyz: list[tuple[float, float, float]] = field(default_factory=list)
    quat: list[tuple[float, float, float, float]] = field(default_factory=list)
    static: bool = False


TIME_SOURCES = ("header", "receive")
CANDIDATE_PARENTS = ("map", "odom", "world")  # REP 105: the first linked to the child is the poses' frame


def norm_frame(name: str) -> str:
    """ROS 1 frame ids may carry a leading '/'; TF itself ignores it."""
    return name.strip().lstrip("/")


def check_time_source(value: str, what: str) -> str:
    """`header` (a message's header.stamp, its receive time when the stamp is zero) or
    `receive` (the time it was received: logged by the bag, or seen by the link)."""
    if value not in TIME_SOURCES:
        raise InputError(f"{what}: time_source must be 'header' or 'receive', got {value!r}")
    return value


class TfTree:
    """Collects TransformStamped samples and answers parent -> child pose tracks."""

    def __init__(self) -> None:
        self.edges: dict[tuple[str, str], Edge] = {}
        self.parent_of: dict[str, str] = {}

    def add(
        self,
        parent: str,
        child: str,
        t: float,
        xyz: tuple[float, float, float],
        quat: tuple[float, float, float, float],
        static: bool,
    ) -> None:
        parent, child = norm_frame(parent), norm_frame(child)
        e = self.edges.setdefault((parent, child), Edge())
        e.static = e.static or static
        e.t.append(t)
        e.xyz.append(xyz)
        e.quat.append(quat)
        self.parent_of.setdefault(child, parent)

    @property
    def frames(self) -> list[str]:
        return sorted({f for edge in self.edges for f in edge})

    def _up(self, frame: str) -> list[str]:
        chain = [frame]
        while chain[-1] in self.parent_of and len(chain) <= len(self.parent_of):
            chain.append(self.parent_of[chain[-1]])
        return chain

    def default_parent(self, child: str, candidates: tuple[str, ...] = CANDIDATE_PARENTS) -> str | None:
        """The first of `candidates` that is an ancestor of child."""
        up = self._up(norm_frame(child))
        return next((c for c in candidates if c in up[1:]), None)

    def require(self, frame: str, name: str = "tf") -> None:
        """Raise InputError naming the known frames when `frame` never appears in the tree."""
        if norm_frame(frame) not in self.frames:
            raise InputError(
                f"{name}: frame {frame!r} not in /tf (frames: {', '.join(self.frames) or 'none'})"
            )

    def track(self, parent: str, child: str, name: str = "tf") -> PoseTrack:
        """Pose of `child` in `parent` over time (see the module docstring)."""
        parent, child = norm_frame(parent), norm_frame(child)
        for f in (parent, child):
            self.require(f, name)
        up_c, up_p = self._up(child), self._up(parent)
        anc = next((f for f in up_c if f in up_p), None)
        if anc is None:
            raise InputError(f"{name}: frames {parent!r} and {child!r} are not connected in /tf")
        links_c = list(zip(up_c[1 : up_c.index(anc) + 1], up_c[: up_c.index(anc)], strict=True))[::-1]
        links_p = list(zip(up_p[1 : up_p.index(anc) + 1], up_p[: up_p.index(anc)], strict=True))[::-1]
        moving = [self.edges[k] for k in links_c + links_p if not self.edges[k].static]
        if not moving:
            raise InputError(f"{name}: {parent} -> {child} only has static transforms, so no motion")
        t0 = max(min(e.t) for e in moving)
        t1 = min(max(e.t) for e in moving)
        ts = np.unique(np.concatenate([np.asarray(e.t) for e in moving]))
        ts = ts[(ts >= t0) & (ts <= t1)]
        if ts.size == 0:
            raise InputError(f"{name}: the moving transforms of {parent} -> {child} never overlap in time")
        p_c, r_c = self._compose(links_c, ts)
        p_p, r_p = self._compose(links_p, ts)
        r_inv = r_p.inv()
        xyz = r_inv.apply(p_c - p_p)
        rot = r_inv * r_c
        return PoseTrack(ts, xyz, rot.as_quat(), name=f"{name} {parent}->{child}")

    def _compose(self, links: list[tuple[str, str]], ts: np.ndarray) -> tuple[np.ndarray, Rotation]:
        """T_anc_frame at every time in ts, composing the links from the ancestor downwards."""
        p = np.zeros((len(ts), 3))
        r = Rotation.identity(len(ts))
        for key in links:
            e = self.edges[key]
            if e.static:
                p_e = np.tile(np.asarray(e.xyz[-1], dtype=np.float64), (len(ts), 1))
                r_e = Rotation.from_quat(np.tile(np.asarray(e.quat[-1], dtype=np.float64), (len(ts), 1)))
            else:
                tr = PoseTrack.from_samples(e.t, e.xyz, np.asarray(e.quat), name="tf edge")
                _, p_e, _, q_e = tr.interpolate_many(ts)
                assert q_e is not None
                r_e = Rotation.from_quat(q_e)
            p = p + r.apply(p_e)
            r = r * r_e
        return p, r


# ----------------------------------------------------------------------------- live buffers
# A live stream asks one question per image: the pose at its stamp. The buffers below answer it
# by bisection over a bounded window of samples, so a message costs O(1) to add (amortized, in
# time order) and a lookup O(log n), whatever the stream's length; `TfTree` above rebuilds a
# whole track and is for recordings.

NO_POSE = "no pose yet"
TOO_OLD = "older than the pose history"
TOO_NEW = "newer than the newest pose"
GAP = "pose gap too long"
REFUSED = "tf frame refused (a second parent, or too many frames)"
MAX_GAP = 1.0  # seconds: the longest gap between two samples of a moving transform interpolated across


class PoseBuffer:
    """The recent samples of one moving transform, at most `size` and `history` seconds back.
    Samples come mostly in time order; a late one is inserted in place."""

    def __init__(self, history: float = 30.0, size: int = 10_000, max_gap: float = MAX_GAP) -> None:
        self.history = history
        self.size = size
        self.max_gap = max_gap
        self.t: list[float] = []
        self.v: list[tuple[tuple[float, float, float], tuple[float, float, float, float]]] = []

    def add(self, t: float, xyz: tuple[float, float, float], quat: tuple[float, float, float, float]) -> None:
        if self.t and t < self.t[-1]:
            i = bisect.bisect_left(self.t, t)
            if i < len(self.t) and self.t[i] == t:
                self.v[i] = (xyz, quat)
                return
            self.t.insert(i, t)
            self.v.insert(i, (xyz, quat))
        elif self.t and t == self.t[-1]:
            self.v[-1] = (xyz, quat)
        else:
            self.t.append(t)
            self.v.append((xyz, quat))
        over = max(len(self.t) - self.size, 0)
        cut = bisect.bisect_left(self.t, self.t[-1] - self.history) - 1
        drop = max(over, cut)
        if drop >= 64 or over:  # in chunks: deleting a list's head is O(n)
            del self.t[:drop], self.v[:drop]

    @property
    def newest(self) -> float | None:
        return self.t[-1] if self.t else None

    def __len__(self) -> int:
        return len(self.t)

    def at(
        self, t: float, nearest: bool = False
    ) -> tuple[tuple[float, float, float], tuple[float, float, float, float]] | str:
        """The transform at t (linear position, spherical rotation), or why there is none;
        `nearest`: the sample nearest t instead, when within `max_gap`."""
        if not self.t:
            return NO_POSE
        if nearest:
            return self._nearest(t)
        if t > self.t[-1]:
            return TOO_NEW
        if t < self.t[0]:
            return TOO_OLD
        i = bisect.bisect_left(self.t, t)
        if self.t[i] == t:
            return self.v[i]
        t0, t1 = self.t[i - 1], self.t[i]
        if t1 - t0 > self.max_gap:
            return GAP
        a = (t - t0) / (t1 - t0)
        (p0, q0), (p1, q1) = self.v[i - 1], self.v[i]
        xyz = (p0[0] + a * (p1[0] - p0[0]), p0[1] + a * (p1[1] - p0[1]), p0[2] + a * (p1[2] - p0[2]))
        return xyz, _slerp(q0, q1, a)

    def _nearest(
        self, t: float
    ) -> tuple[tuple[float, float, float], tuple[float, float, float, float]] | str:
        """As `ingest.poses.PoseTrack.nearest`: the earlier sample on a tie."""
        if t > self.t[-1] + self.max_gap:
            return TOO_NEW
        if t < self.t[0] - self.max_gap:
            return TOO_OLD
        i = bisect.bisect_left(self.t, t)
        j = min((k for k in (i - 1, i) if 0 <= k < len(self.t)), key=lambda k: abs(self.t[k] - t))
        return self.v[j] if abs(self.t[j] - t) <= self.max_gap else GAP


def _slerp(
    q0: tuple[float, float, float, float], q1: tuple[float, float, float, float], a: float
) -> tuple[float, float, float, float]:
    dot = sum(x * y for x, y in zip(q0, q1, strict=True))
    if dot < 0:
        q1, dot = (-q1[0], -q1[1], -q1[2], -q1[3]), -dot
    if dot > 0.9995:  # nearly the same rotation: normalized lerp
        q = tuple(x + a * (y - x) for x, y in zip(q0, q1, strict=True))
    else:
        th = math.acos(dot)
        s0, s1 = math.sin((1 - a) * th) / math.sin(th), math.sin(a * th) / math.sin(th)
        q = tuple(s0 * x + s1 * y for x, y in zip(q0, q1, strict=True))
    n = math.sqrt(sum(c * c for c in q))
    return (q[0] / n, q[1] / n, q[2] / n, q[3] / n)


def _compose(
    a: tuple[tuple[float, float, float], tuple[float, float, float, float]],
    b: tuple[tuple[float, float, float], tuple[float, float, float, float]],
) -> tuple[tuple[float, float, float], tuple[float, float, float, float]]:
    """T_a * T_b (a's frame -> b's child)."""
    (pa, qa), (pb, qb) = a, b
    ra = Rotation.from_quat(qa)
    p = ra.apply(pb) + np.asarray(pa)
    q = (ra * Rotation.from_quat(qb)).as_quat()
    return (float(p[0]), float(p[1]), float(p[2])), (float(q[0]), float(q[1]), float(q[2]), float(q[3]))


class TfBuffer:
    """/tf and /tf_static, bounded: each child frame has one parent and either one static
    transform or a `PoseBuffer` (at most `size` samples and `history` seconds, gaps up to
    `max_gap` interpolated), at most `max_frames` frames. `lookup(parent, child, t)` walks up
    from child to parent, each moving transform interpolated at t, as tf2 does."""

    def __init__(
        self, history: float = 30.0, size: int = 10_000, max_frames: int = 1000, max_gap: float = MAX_GAP
    ) -> None:
        self.history, self.size, self.max_frames, self.max_gap = history, size, max_frames, max_gap
        self.parent_of: dict[str, str] = {}
        self.static: dict[str, tuple[tuple[float, float, float], tuple[float, float, float, float]]] = {}
        self.moving: dict[str, PoseBuffer] = {}

    def add(
        self,
        parent: str,
        child: str,
        t: float,
        xyz: tuple[float, float, float],
        quat: tuple[float, float, float, float],
        static: bool,
    ) -> bool:
        """Add one transform; False when refused (too many frames, or a second parent)."""
        parent, child = norm_frame(parent), norm_frame(child)
        known = self.parent_of.get(child)
        if known is None:
            if len(self.parent_of) >= self.max_frames or parent == child:
                return False
            self.parent_of[child] = parent
        elif known != parent:
            return False
        if static:
            self.static[child] = (xyz, quat)
        else:
            buf = self.moving.get(child)
            if buf is None:
                buf = self.moving[child] = PoseBuffer(self.history, self.size, self.max_gap)
            buf.add(t, xyz, quat)
        return True

    def __len__(self) -> int:
        """The moving samples kept, all frames together (bounded: see the class docstring)."""
        return sum(len(b) for b in self.moving.values())

    def default_parent(self, child: str, candidates: tuple[str, ...] = CANDIDATE_PARENTS) -> str | None:
        """The first of `candidates` that /tf links to `child` so far (None: none yet)."""
        return next((f for f in candidates if f and self.chain(f, child) is not None), None)

    def chain(self, parent: str, child: str) -> list[str] | None:
        """Frames from child up to parent (child first, parent excluded), None when not connected."""
        out, f = [], norm_frame(child)
        parent = norm_frame(parent)
        while f != parent:
            out.append(f)
            nxt = self.parent_of.get(f)
            if nxt is None or len(out) > len(self.parent_of):
                return None
            f = nxt
        return out

    def newest(self, parent: str, child: str) -> float | None:
        """The latest time the whole chain is known at (None: not connected, or static only)."""
        chain = self.chain(parent, child)
        if chain is None:
            return None
        times = [self.moving[f].newest for f in chain if f in self.moving]
        known = [t for t in times if t is not None]
        return min(known) if known else None

    def lookup(
        self, parent: str, child: str, t: float, nearest: bool = False
    ) -> tuple[tuple[float, float, float], tuple[float, float, float, float]] | str:
        """T_parent_child at t, or why there is none (`NO_POSE`, `TOO_OLD`, `TOO_NEW`, `GAP`, no
        transform); `nearest`: each moving transform's sample nearest t (within `max_gap`)."""
        chain = self.chain(parent, child)
        if chain is None:
            return f"no transform from {parent!r} to {child!r} in tf yet"
        out: tuple[tuple[float, float, float], tuple[float, float, float, float]] = (
            (0.0, 0.0, 0.0),
            (0.0, 0.0, 0.0, 1.0),
        )
        for f in reversed(chain):  # from the parent's side down to the child
            if f in self.moving:
                step = self.moving[f].at(t, nearest)
                if isinstance(step, str):
                    return step
            else:
                step = self.static[f]
            out = _compose(out, step)
        return out
