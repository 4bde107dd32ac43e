"""Which recording a frame came from, independent of where the recording lies on disk.

Ingest stores `<format>:<name>@<fingerprint>` in `MemoryRecord.source` (e.g.
`tum:rgbd_dataset_freiburg1_rpy@3fa2c1d09e4b`) and skips a frame when the memory already holds
one with the same source identity and the same frame index or timestamp: re-running an ingest
resumes it, and appending a recording twice stores it once. The fingerprint is a hash of the
recording's *beginning* (the first MiB of a video or bag file, the start of TUM's rgb.txt, the
names and sizes of a folder's first images and the first image's bytes), so:

* a moved or renamed parent folder, or a relative instead of an absolute path, is the same
  recording (the path is not part of it);
* two recordings with the same file or folder name are different recordings (their beginnings
  differ);
* a recording that grew (more images, a longer rgb.txt, a fuller copy of a truncated video)
  keeps its identity, so ingesting it again adds only the new frames.

The name part is for people reading search results; only the whole string is compared.
"""

from __future__ import annotations

import hashlib
from collections.abc import Iterable
from pathlib import Path

HEAD_BYTES = 1 << 20


def file_head(path: Path, n: int = HEAD_BYTES) -> bytes:
    """The first `n` bytes of a file (all of a shorter one)."""
    with open(path, "rb") as f:
        return f.read(n)


def make_identity(kind: str, name: str, parts: Iterable[bytes | str]) -> str:
    """`kind:name@<12 hex of sha256 over the parts>`."""
    h = hashlib.sha256()
    for p in parts:
        b = p.encode("utf-8", "surrogateescape") if isinstance(p, str) else p
        h.update(len(b).to_bytes(8, "little"))
        h.update(b)
    return f"{kind}:{name}@{h.hexdigest()[:12]}"


def source_identity(source: object) -> str:
    """A source's identity: its `identity()` when it has one (every built-in source does),
    else its `name` (a third-party source without `identity()` is then known by name only)."""
    ident = getattr(source, "identity", None)
    if callable(ident):
        return str(ident())
    return str(getattr(source, "name", type(source).__name__))


def derived_map_id(source: object) -> tuple[str, str]:
    """(map identity, frame) of a recording's poses when the user names no map: its frame
    (REP 105; a source's `frame_id`, `map` when it says none) in that recording, so two
    recordings are two maps until someone says they share one (`ingest --map-id`)."""
    frame = str(getattr(source, "frame_id", None) or "map")
    return f"{source_identity(source)}#{frame}", frame
