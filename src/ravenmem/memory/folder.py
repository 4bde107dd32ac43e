"""What lies inside a memory folder: the one place that names its files.

A memory is a folder. Everything ravenmem keeps in it is named here, and every part that reads
or writes one of these files (the facade, the lock, the manifest, crash recovery, the lifelong
sidecars, maps, missions, the agent's caches, the ROS 2 node, the service) takes the name from
here, so the folder's layout can be read, and changed, in one file:

| name | what | written by |
| --- | --- | --- |
| `memory.json` | the manifest: embedder, store, thumbnail and OCR settings, ingest history | `memory.manifest` |
| `writer.lock` | the one writer's lock (pid, command, since) | `memory.lock` |
| `pending-thumbs-<id>.json` | a thumbnail journal while a batch commits | `memory.recovery` |
| `pending-text-<id>.npz` | pictures whose text is read after they are stored | `memory.text` |
| `pending-thumbs-<id>.json.aside` | a journal recovery could not act on, kept for a person | `memory.recovery` |
| `pending-text-<id>.npz.aside` | a text journal recovery could not act on, kept for a person | `memory.text` |
| `thumbs/<ms>_<hex>.jpg` | thumbnails | `Memory.add_frames` |
| `lifelong.sqlite` | consolidated groups (count, span) | `memory.groups` |
| `map.npz`, `map.json` | the occupancy grid and its settings | `nav.grid` |
| `explore.json` | what an exploration mission covered | `robot.mission` |
| `captions.sqlite` | the caption baseline's captions | `agent.captions` |
| `offline_calibration.json` | the offline reasoner's calibrated threshold | `agent.offline` |
| `study_memory.json` | an ablation study's copy of a memory is complete | `eval.studies` |
| `anchor/poses.npz` | every memory's pose before `ravenmem align --apply` moved it | `memory.anchor` |
| `anchor/pending.json` | a re-anchoring under way (finished by the next writer) | `memory.anchor` |
| `anchor/pending.json.aside` | an unreadable re-anchoring journal, kept for a person (the poses follow the manifest) | `memory.transform` |
| `anchor/map.npz`, `anchor/map.json` | the occupancy map before it was re-anchored | `nav.align` |

The store's own files (`store.sqlite`, `index.faiss`, `columns.cache` for the embedded store; a
Milvus Lite `NAME.db` the user named) belong to the store backend, which lives a floor below
and is handed the folder (or the file) by the manifest (`Manifest.store_uri`).
"""

from __future__ import annotations

import os
import re
import shutil
from pathlib import Path

MANIFEST = "memory.json"
LOCK = "writer.lock"
THUMBS = "thumbs"
GROUPS = "lifelong.sqlite"
MAP_GRID = "map.npz"
MAP_META = "map.json"
EXPLORE = "explore.json"
CAPTIONS = "captions.sqlite"
OFFLINE_CALIBRATION = "offline_calibration.json"
STUDY_DONE = "study_memory.json"
ANCHOR = "anchor"  # a folder: the originals of a re-anchored memory (`ravenmem align`)
ANCHOR_POSES = f"{ANCHOR}/poses.npz"
ANCHOR_JOURNAL = f"{ANCHOR}/pending.json"

JOURNAL_PREFIX = "pending-thumbs-"
JOURNAL_NAME = re.compile(r"pending-thumbs-[0-9a-f]{12}\.json")
TEXT_JOURNAL_PREFIX = "pending-text-"
TEXT_JOURNAL_NAME = re.compile(r"pending-text-[0-9a-f]{12}\.npz")
THUMB_NAME = re.compile(r"-?\d+_[0-9a-f]{8}\.jpg")


def journal_name(token: str) -> str:
    """A thumbnail journal's file name (`token`: 12 hex digits)."""
    return f"{JOURNAL_PREFIX}{token}.json"


def text_journal_name(token: str) -> str:
    """A text journal's file name (`token`: 12 hex digits)."""
    return f"{TEXT_JOURNAL_PREFIX}{token}.npz"


def aside_name(journal: str) -> str:
    """Where recovery moves a journal it cannot act on (kept for a person to look at)."""
    return f"{journal}.aside"


def thumb_name(t: float, token: str) -> str:
    """A new thumbnail's path relative to the folder: its time in ms (so `ls` sorts by time)
    and 8 hex digits (`token`) that keep two frames of one millisecond apart."""
    return f"{THUMBS}/{int(t * 1000):015d}_{token}.jpg"


def is_memory(folder: Path) -> bool:
    """Whether `folder` holds a memory (its manifest)."""
    try:
        return (folder / MANIFEST).is_file()
    except OSError:
        return False


def thumb_file(folder: Path, rel: str | None) -> Path | None:
    """The thumbnail file of a record's `image_path`, or None (no thumbnail, an external file,
    or a name ravenmem would not have written: only such files are ever deleted)."""
    if not rel or Path(rel).is_absolute():
        return None
    p = folder / rel
    if p.parent != folder / THUMBS or not THUMB_NAME.fullmatch(p.name):
        return None
    return p


def file_size(p: Path) -> int:
    """Bytes of a file, 0 when it is gone (a thumbnail deleted meanwhile)."""
    try:
        return p.stat().st_size
    except OSError:
        return 0


def has_thumbs(folder: Path) -> bool:
    """Whether the folder holds any thumbnail (then its store must be there too)."""
    try:
        with os.scandir(folder / THUMBS) as it:
            return any(THUMB_NAME.fullmatch(e.name) for e in it)
    except OSError:
        return False


def thumbs_bytes(folder: Path) -> int:
    """Bytes of every thumbnail in the folder."""
    thumbs = folder / THUMBS
    return sum(file_size(p) for p in thumbs.glob("*.jpg")) if thumbs.exists() else 0


class Created:
    """What `create` made, so that a failure removes exactly that: the top folder it created
    (with everything below), or the entries it added to a folder that existed (and was empty)."""

    def __init__(self, folder: Path) -> None:
        self.folder = folder
        top = folder
        while not top.parent.exists() and top.parent != top:
            top = top.parent
        self.top: Path | None = None if folder.exists() else top
        self.before = set(os.listdir(folder)) if folder.exists() else set()

    def undo(self) -> None:
        if self.top is not None:
            shutil.rmtree(self.top, ignore_errors=True)
            return
        if not self.folder.is_dir():
            return
        for name in set(os.listdir(self.folder)) - self.before:
            p = self.folder / name
            if p.is_dir() and not p.is_symlink():
                shutil.rmtree(p, ignore_errors=True)
            else:
                p.unlink(missing_ok=True)
