"""The rigid transform of a re-anchoring and the journal's application (`finish`), below the
memory's writer: the writer finishes a journal a killed writer left (`Core.acquire_writer`), and
`anchor` (which writes journals) builds on it. See `ravenmem.memory.anchor` for the scheme."""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import InputError
from ..store.base import Store
from ..types import MAX_COORD, Pose
from .folder import ANCHOR_JOURNAL, ANCHOR_POSES
from .manifest import Manifest
from .recovery import set_aside

_CHUNK = 5000  # records read or written per store call
MAX_SHIFT = 2 * MAX_COORD  # metres a transform may shift a map (both maps within +-MAX_COORD)
MAX_TURN = 4 * math.pi  # radians a transform may turn a map (720 degrees)


@dataclass(frozen=True)
class Transform:
    """A rigid transform of the map plane (REP 103: z up): a rotation of `yaw` radians about z,
    then a translation (x, y, z) in metres. `apply` maps a pose of the source map into the
    target map."""

    x: float = 0.0
    y: float = 0.0
    z: float = 0.0
    yaw: float = 0.0

    def __post_init__(self) -> None:
        if not all(math.isfinite(v) for v in (self.x, self.y, self.z, self.yaw)):
            raise InputError(f"transform: every value must be finite, got {self.as_list()}")
        # one map into another: a shift no larger than two maps' range, a turn of at most two
        # rounds; anything else is a typo (1e308 degrees turns every pose to a random heading)
        if max(abs(self.x), abs(self.y), abs(self.z)) > MAX_SHIFT or abs(self.yaw) > MAX_TURN:
            raise InputError(
                f"transform {[float(f'{v:.6g}') for v in self.as_list()]}: out of range (x, y, z within "
                f"+-{MAX_SHIFT:g} m, yaw within +-{math.degrees(MAX_TURN):g} degrees)"
            )

    @classmethod
    def of(cls, values: Any) -> Transform:
        """From [x, y, z, yaw] (yaw in radians)."""
        try:
            x, y, z, yaw = (float(v) for v in values)
        except (TypeError, ValueError):
            raise InputError(f"transform: expected [x, y, z, yaw], got {values!r}") from None
        return cls(x, y, z, yaw)

    def as_list(self) -> list[float]:
        return [self.x, self.y, self.z, self.yaw]

    @property
    def is_identity(self) -> bool:
        return self.as_list() == [0.0, 0.0, 0.0, 0.0]

    def inverse(self) -> Transform:
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        return Transform(-(c * self.x + s * self.y), -(-s * self.x + c * self.y), -self.z, -self.yaw)

    def then(self, other: Transform) -> Transform:
        """This transform followed by `other` (other . self)."""
        x, y = other.xy(self.x, self.y)
        yaw = math.atan2(math.sin(self.yaw + other.yaw), math.cos(self.yaw + other.yaw))
        return Transform(x, y, self.z + other.z, yaw)

    def xy(self, x: float, y: float) -> tuple[float, float]:
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        return (c * x - s * y + self.x, s * x + c * y + self.y)

    def apply(self, p: Pose) -> Pose:
        """The pose moved: position rotated and shifted, orientation turned about z."""
        x, y = self.xy(p.x, p.y)
        yaw = math.atan2(math.sin(p.yaw + self.yaw), math.cos(p.yaw + self.yaw))
        if p.quat is None:
            return Pose(x, y, p.z + self.z, yaw)
        qx, qy, qz, qw = p.quat
        s, c = math.sin(self.yaw / 2.0), math.cos(self.yaw / 2.0)
        turned = (c * qx - s * qy, c * qy + s * qx, c * qz + s * qw, c * qw - s * qz)
        return Pose.from_quaternion(x, y, p.z + self.z, *turned)


def load_originals(folder: Path) -> tuple[np.ndarray, np.ndarray]:
    """(ids, (N, 8) x y z yaw qx qy qz qw, NaN quaternion when none) of the saved originals."""
    p = folder / ANCHOR_POSES
    if not p.is_file():
        return np.empty(0, np.int64), np.empty((0, 8), np.float64)
    try:
        with np.load(p, allow_pickle=False) as z:
            ids, table = np.asarray(z["ids"], np.int64), np.asarray(z["poses"], np.float64)
    except (OSError, ValueError, KeyError) as e:
        raise InputError(f"{p}: the saved original poses cannot be read ({e})") from None
    if table.shape != (len(ids), 8):
        raise InputError(f"{p}: malformed original poses (shape {table.shape})")
    return ids, table


def finish(folder: Path, store: Store, manifest: Manifest) -> Manifest | None:
    """Apply a re-anchoring journal left in `folder` (by this writer, or one that was killed):
    every memory's pose becomes the journal's transform of its original, the manifest takes the
    journal's identity, the journal goes. Returns the new manifest, None when there was none.

    A journal that cannot be read (it is written atomically, so only a hand or a damaged disk
    makes one) cannot wedge the memory: it is logged and set aside (`recovery.set_aside`), and the
    poses are put back to what the manifest says (its transform of the originals), undoing any
    part of the re-anchoring that was applied before the writer died."""
    path = folder / ANCHOR_JOURNAL
    if not path.is_file():
        return None
    map_id: str | None
    frame_id: str | None
    try:
        journal = json.loads(path.read_text(encoding="utf-8"))
        anchor = journal["anchor"]
        map_id, frame_id = str(journal["map_id"]), str(journal["frame_id"])
        t = Transform.of(anchor["transform"]) if anchor else Transform()
    except (OSError, ValueError, KeyError, TypeError, InputError) as e:
        set_aside(path, f"unreadable ({e}); poses kept as the manifest says", "re-anchoring journal")
        anchor, map_id, frame_id = manifest.anchor, manifest.map_id, manifest.frame_id
        t = Transform.of(anchor["transform"]) if anchor else Transform()
    ids, table = load_originals(folder)
    stored = set(store.select().tolist())
    keep = [k for k, i in enumerate(ids.tolist()) if i in stored]
    for part in chunks(np.asarray(keep, np.int64)):
        store.set_poses(ids[part].tolist(), [t.apply(pose_of(table[k])) for k in part])
    manifest.anchor, manifest.map_id, manifest.frame_id = anchor, map_id, frame_id
    manifest.save(folder)
    path.unlink(missing_ok=True)
    return manifest


def pose_table(poses: list[Pose]) -> np.ndarray:
    return np.asarray([[p.x, p.y, p.z, p.yaw, *(p.quat or (np.nan,) * 4)] for p in poses], np.float64)


def pose_of(row: np.ndarray) -> Pose:
    x, y, z, yaw, *q = (float(v) for v in row)
    return Pose(x, y, z, yaw, None if math.isnan(q[0]) else (q[0], q[1], q[2], q[3]))


def chunks(a: np.ndarray) -> list[list[int]]:
    v = np.asarray(a).tolist()
    return [v[s : s + _CHUNK] for s in range(0, len(v), _CHUNK)]
