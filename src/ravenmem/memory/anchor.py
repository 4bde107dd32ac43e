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
import time
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import InputError
from ..fsio import atomic_write, atomic_write_json
from ..types import Pose
from .core import Core
from .folder import ANCHOR, ANCHOR_JOURNAL, ANCHOR_POSES
from .manifest import Manifest, is_name
from .transform import Transform, chunks, finish, load_originals, pose_of, pose_table

DEFAULT_FRAME = "map"


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
            _check_moves(self, transform)  # every pose it would write, before anything is written
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


def _check_moves(mem: Anchoring, t: Transform) -> None:
    """Refuse a transform that would move any memory out of the map's range (a one-line
    InputError naming the first such memory), before a journal is written: a journal the
    writer cannot finish would stop every later write."""
    ids, table = load_originals(mem.path)
    have = set(ids.tolist())
    back = mem.current_transform().inverse()
    for part in chunks(np.arange(len(ids))):
        for k in part:
            _moved(t, pose_of(table[k]), int(ids[k]))
    for chunk in chunks(mem.store.select()):
        todo = [i for i in chunk if i not in have]
        for rec in mem.store.get(todo) if todo else []:
            _moved(t, back.apply(rec.pose), rec.id)


def _moved(t: Transform, original: Pose, memory_id: int) -> None:
    try:
        t.apply(original)
    except InputError as e:
        raise InputError(
            f"transform {t.as_list()} would move memory {memory_id} out of the map ({e}); nothing was moved"
        ) from None


def _keep_originals(mem: Anchoring) -> None:
    """Save the first-stored pose of every memory not in `anchor/poses.npz` yet (memories
    added since the last re-anchoring were added in its map: put back through its inverse)."""
    ids, poses = load_originals(mem.path)
    have = set(ids.tolist())
    back = mem.current_transform().inverse()
    new_ids: list[int] = []
    new_poses: list[Pose] = []
    for chunk in chunks(mem.store.select()):
        todo = [i for i in chunk if i not in have]
        for rec in mem.store.get(todo) if todo else []:
            new_ids.append(rec.id)
            new_poses.append(back.apply(rec.pose))
    if not new_ids:
        return
    all_ids = np.concatenate([ids, np.asarray(new_ids, np.int64)])
    table = np.concatenate([poses, pose_table(new_poses)])
    buf = io.BytesIO()
    np.savez(buf, ids=all_ids, poses=table)
    (mem.path / ANCHOR).mkdir(exist_ok=True)
    atomic_write(mem.path / ANCHOR_POSES, buf.getvalue())
