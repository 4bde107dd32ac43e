"""Which map a memory's poses are in, and moving them into another one (re-anchoring).

Frames (REP 105): a memory records the frame its poses are in (`frame_id`: `map`, or `odom`
when the robot had no map frame) and the identity of that map (`map_id`: a name the user gave,
`ingest --map-id` or `serve --map-id`, or one derived from its first recording). A memory holds
one map: a recording named to be in another one, or with poses of another frame, is refused
(`claim_map`), because coordinates of two maps side by side would point at the wrong places
without anything saying so; a recording that names no map is taken to be in the memory's (and
the ingest says so). Memories written before this was recorded read as frame `map`, map
`memory:<folder name>`, and take the identity of the next recording added.

Re-anchoring (`reanchor`): after `ravenmem align` found (or was given) the rigid transform
from this memory's map into another's, every pose is put through it, nothing re-embedded. The
poses as they were first stored are kept (`anchor/poses.npz`), so the next correction (a loop
closure, a re-localisation) is applied to the originals, not on top of the last one, and
`unanchor` restores them. Crash-safe through the writer handle: the originals are saved before
anything moves, then a journal (`anchor/pending.json`) names the transform and the target map;
the store takes the new poses in one transaction, the manifest the new identity, and the
journal goes. A writer killed in between leaves the journal, and the next writer
(`Memory.acquire_writer`) applies it again from the originals (`finish`).
"""

from __future__ import annotations

import io
import json
import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import InputError
from ..fsio import atomic_write, atomic_write_json
from ..store.base import Store
from ..types import Pose
from .core import Core
from .folder import ANCHOR, ANCHOR_JOURNAL, ANCHOR_POSES
from .manifest import Manifest, is_name

DEFAULT_FRAME = "map"
_CHUNK = 5000  # records read or written per store call


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


def map_identity(manifest: Manifest, folder: Path) -> dict[str, Any]:
    """What `info` and every answer show: the poses' frame, their map, the re-anchoring applied
    (the defaults for memories written before these were recorded: see the module docstring)."""
    return {
        "frame_id": manifest.frame_id or DEFAULT_FRAME,
        "map_id": manifest.map_id or f"memory:{folder.name}",
        "anchor": manifest.anchor,
    }


class Anchoring(Core):
    """`Memory.frame_id`, `map_id`, `claim_map`, `reanchor` and `unanchor`."""

    @property
    def frame_id(self) -> str:
        """The frame the poses are in (REP 105): `map`, or `odom` when there was no map frame."""
        return str(map_identity(self.manifest, self.path)["frame_id"])

    @property
    def map_id(self) -> str:
        """The identity of the map the poses are in."""
        return str(map_identity(self.manifest, self.path)["map_id"])

    def map_identity(self) -> dict[str, Any]:
        """`frame_id`, `map_id` and `anchor`, as `info` and every answer show them."""
        return map_identity(self.manifest, self.path)

    def claim_map(
        self,
        map_id: str | None = None,
        frame_id: str | None = None,
        given: bool = True,
        what: str = "the recording",
    ) -> str | None:
        """Say that poses about to be added are in map `map_id`, frame `frame_id` (None: not
        said). A memory that has no identity yet takes it. One in another map refuses a map the
        user named (`given`) with a one-line `InputError` naming both (nothing is written); a
        map derived from an unnamed recording is taken to be the memory's, and the note saying
        so is returned. Poses of another frame are always refused."""
        for name, v in (("map id", map_id), ("frame", frame_id)):
            if v is not None and not is_name(v):
                raise InputError(f"{name} {v!r}: expected 1 to 200 printable characters")
        m = self.manifest
        note = None
        if map_id is not None and m.map_id is not None and map_id != m.map_id:
            if given:
                raise InputError(
                    f"{what} is in map {map_id!r} but memory {self.path} is in map {m.map_id!r}: put "
                    "it in another memory and `ravenmem align` the two, or name the memory's map"
                )
            note = f"{what} names no map: taken to be in the memory's, {m.map_id!r} (--map-id says otherwise)"
            map_id = None
        if frame_id is not None and m.frame_id is not None and frame_id != m.frame_id:
            raise InputError(
                f"{what} has poses in frame {frame_id!r} but memory {self.path} has them in "
                f"{m.frame_id!r}: a memory holds poses of one frame"
            )
        if (map_id is None or m.map_id == map_id) and (frame_id is None or m.frame_id == frame_id):
            return note
        with self.writer().change():
            m.map_id = map_id if map_id is not None else m.map_id or self.map_id
            m.frame_id = frame_id if frame_id is not None else m.frame_id or DEFAULT_FRAME
            m.save(self.path)
        return note

    # ---------------------------------------------------------------- re-anchoring
    def reanchor(self, transform: Transform, map_id: str, frame_id: str | None = None) -> int:
        """Move every pose into map `map_id` through `transform` (from the map the poses were
        first stored in); returns how many memories moved. See the module docstring."""
        if not is_name(map_id):
            raise InputError(f"map id {map_id!r}: expected 1 to 200 printable characters")
        writer = self.writer()
        with writer.change():
            origin = dict((self.manifest.anchor or {}).get("from") or {})
            origin = origin or {"frame_id": self.frame_id, "map_id": self.map_id}
            _keep_originals(self)
            record = {
                "transform": transform.as_list(),
                "from": origin,
                "applied": time.time(),
            }
            journal = {"anchor": record, "map_id": map_id, "frame_id": frame_id or self.frame_id}
            atomic_write_json(self.path / ANCHOR_JOURNAL, journal)
            self.manifest = finish(self.path, self.store, self.manifest) or self.manifest
            return self.count()

    def unanchor(self) -> int:
        """Put every pose back where it was first stored (undo `reanchor`); how many moved."""
        anchor = self.manifest.anchor
        if anchor is None:
            raise InputError(f"memory {self.path} was never re-anchored: nothing to undo")
        writer = self.writer()
        with writer.change():
            _keep_originals(self)
            origin = anchor["from"]
            journal = {"anchor": None, "map_id": origin["map_id"], "frame_id": origin["frame_id"]}
            atomic_write_json(self.path / ANCHOR_JOURNAL, journal)
            self.manifest = finish(self.path, self.store, self.manifest) or self.manifest
            return self.count()

    def current_transform(self) -> Transform:
        """The transform the stored poses went through (identity when never re-anchored)."""
        a = self.manifest.anchor
        return Transform.of(a["transform"]) if a else Transform()


def _keep_originals(mem: Anchoring) -> None:
    """Save the first-stored pose of every memory not in `anchor/poses.npz` yet (memories
    added since the last re-anchoring were added in its map: put back through its inverse)."""
    ids, poses = load_originals(mem.path)
    have = set(ids.tolist())
    back = mem.current_transform().inverse()
    new_ids: list[int] = []
    new_poses: list[Pose] = []
    for chunk in _chunks(mem.store.select()):
        todo = [i for i in chunk if i not in have]
        for rec in mem.store.get(todo) if todo else []:
            new_ids.append(rec.id)
            new_poses.append(back.apply(rec.pose))
    if not new_ids:
        return
    all_ids = np.concatenate([ids, np.asarray(new_ids, np.int64)])
    table = np.concatenate([poses, _pose_table(new_poses)])
    buf = io.BytesIO()
    np.savez(buf, ids=all_ids, poses=table)
    (mem.path / ANCHOR).mkdir(exist_ok=True)
    atomic_write(mem.path / ANCHOR_POSES, buf.getvalue())


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
    journal's identity, the journal goes. Returns the new manifest, None when there was none."""
    path = folder / ANCHOR_JOURNAL
    if not path.is_file():
        return None
    try:
        journal = json.loads(path.read_text(encoding="utf-8"))
        anchor = journal["anchor"]
        map_id, frame_id = str(journal["map_id"]), str(journal["frame_id"])
        t = Transform.of(anchor["transform"]) if anchor else Transform()
    except (OSError, ValueError, KeyError, TypeError) as e:
        raise InputError(f"{path}: unreadable re-anchoring journal ({e}); nothing was moved by it") from None
    ids, table = load_originals(folder)
    stored = set(store.select().tolist())
    keep = [k for k, i in enumerate(ids.tolist()) if i in stored]
    for part in _chunks(np.asarray(keep, np.int64)):
        store.set_poses(ids[part].tolist(), [t.apply(_pose(table[k])) for k in part])
    manifest.anchor, manifest.map_id, manifest.frame_id = anchor, map_id, frame_id
    manifest.save(folder)
    path.unlink(missing_ok=True)
    return manifest


def _pose_table(poses: list[Pose]) -> np.ndarray:
    return np.asarray([[p.x, p.y, p.z, p.yaw, *(p.quat or (np.nan,) * 4)] for p in poses], np.float64)


def _pose(row: np.ndarray) -> Pose:
    x, y, z, yaw, *q = (float(v) for v in row)
    return Pose(x, y, z, yaw, None if math.isnan(q[0]) else (q[0], q[1], q[2], q[3]))


def _chunks(a: np.ndarray) -> list[list[int]]:
    v = np.asarray(a).tolist()
    return [v[s : s + _CHUNK] for s in range(0, len(v), _CHUNK)]
