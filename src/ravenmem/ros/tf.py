"""Resolve a pose track from a TF tree: parent -> child through any chain of transforms.

Each (parent, child) edge is a time series of transforms (or one static transform from
/tf_static). The pose of `child` in `parent` is found through their common ancestor,
T_parent_child = inv(T_anc_parent) * T_anc_child, with every moving edge interpolated at the
union of the moving edges' sample times (within the span they all cover).
"""

from __future__ import annotations

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

    def prune(self, before: float) -> None:
        """Forget moving samples older than `before`, keeping the last one before it on each edge
        (so a lookup at `before` still interpolates). A live stream keeps bounded memory this way."""
        for e in self.edges.values():
            if e.static or not e.t or e.t[0] >= before:
                continue
            order = np.argsort(np.asarray(e.t), kind="stable")
            ts = np.asarray(e.t)[order]
            keep = order[max(int(np.searchsorted(ts, before, side="right")) - 1, 0) :]
            e.t = [e.t[i] for i in keep]
            e.xyz = [e.xyz[i] for i in keep]
            e.quat = [e.quat[i] for i in keep]

    @property
    def frames(self) -> list[str]:
        return sorted({f for edge in self.edges for f in edge})

    def _up(self, frame: str) -> list[str]:
        chain = [frame]
        while chain[-1] in self.parent_of and len(chain) <= len(self.parent_of):
            chain.append(self.parent_of[chain[-1]])
        return chain

    def default_parent(
        self, child: str, candidates: tuple[str, ...] = ("map", "odom", "world")
    ) -> str | None:
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
