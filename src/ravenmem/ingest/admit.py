"""One way a frame is admitted into a memory: time check, mapper, prefilter, embed, keyframe
rule, add.

A recorded ingest (`ingest.pipeline`, which adds resume) and live adds (`runtime.live`, which
adds a queue) both go through `Admission`, so that a frame a robot streams and the same frame
in a recording meet the same rules, in the same order, with the same skip reasons:

1. `screen(frame)`, the cheap steps, one frame at a time in arrival order: a frame without a
   pose or whose time goes back is skipped (never guessed); a frame with depth is handed to the
   map (every one, keyframe or not); then the keyframe rules that need no embedding (stride,
   rate, motion: `Keyframer.pre`). A skipped frame costs no embedding, so its answer can be
   given at once.
2. `admit(items)`, for the frames that passed, in the same order: one batch through the
   embedder, the novelty rule (`Keyframer.post`) in order, then one `Memory.add_frames` for
   the frames it keeps. An item may instead be the stored embedding of a frame the memory
   already holds (a resumed ingest replays those through the novelty rule).

Keyframe state is kept per lane (a camera: live adds name one per source; a recording is one
lane), so two cameras do not thin each other out.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from ..errors import InputError
from ..types import Frame
from .base import FrameSink
from .keyframes import KeyframeConfig, Keyframer

if TYPE_CHECKING:
    from ..memory import Memory

SKIP_NO_POSE = "no pose"
SKIP_TIME = "non-monotonic timestamp"
MAX_LANES = 64  # keyframe state is kept per lane; a bound keeps a client from growing it


@dataclass(frozen=True)
class Replay:
    """A frame the memory already holds, with its stored embedding: it goes through the novelty
    rule as if it had been embedded now, and is not stored again."""

    embedding: np.ndarray


class _Lane:
    """Keyframe state of one camera: the keyframer, the last time seen, frames numbered."""

    def __init__(self, cfg: KeyframeConfig) -> None:
        self.keyframer = Keyframer(cfg)
        self.last_t = -math.inf
        self.frames = 0


class Admission:
    """The admission stage (see the module docstring) for one memory and one keyframe rule set.

    `mapper` takes every depth frame that passes the time check (`FrameSink`); `number=True`
    numbers each lane's frames in arrival order (`Frame.index`: live frames carry none);
    `text` is `Memory.add_frames`' (`later`: a memory with OCR stores frames before their text
    is read). One caller at a time screens, in order; the frames that pass are admitted in the
    same order (another thread may do that while the next frames are screened).
    """

    def __init__(
        self,
        mem: Memory,
        keyframes: KeyframeConfig | None = None,
        mapper: FrameSink | None = None,
        number: bool = False,
        max_lanes: int = MAX_LANES,
        text: str = "now",
    ) -> None:
        self.mem = mem
        self.text = text
        self.cfg = keyframes if keyframes is not None else KeyframeConfig()
        self.mapper = mapper
        self.number = number
        self.max_lanes = max_lanes
        self._lanes: dict[str, _Lane] = {}

    def lane(self, name: str) -> _Lane:
        """The keyframe state of lane `name` (made on first use; InputError past `max_lanes`)."""
        lane = self._lanes.get(name)
        if lane is None:
            if len(self._lanes) >= self.max_lanes:
                raise InputError(f"more than {self.max_lanes} live sources; reuse a source name")
            lane = self._lanes[name] = _Lane(self.cfg)
        return lane

    def screen(self, f: Frame, lane: str = "") -> str | None:
        """Time check, map, prefilter for one frame: None when it goes on to `admit` (and must,
        in this order), else why it was skipped."""
        st = self.lane(lane)
        if self.number:
            f.index, st.frames = st.frames, st.frames + 1
        if f.pose is None:
            return SKIP_NO_POSE
        if not math.isfinite(f.t) or f.t < st.last_t:
            return SKIP_TIME
        st.last_t = f.t
        if self.mapper is not None and f.depth is not None:
            self.mapper.add(f)  # the map takes every depth frame, keyframe or not, stored or not
            f.depth = None  # not kept past the map
        return st.keyframer.pre(f)

    def admit(self, items: Sequence[tuple[str, Frame | Replay]]) -> list[int | str | None]:
        """Embed the screened frames among `items` ((lane, frame or replay), in screening
        order) in one batch, apply the novelty rule in order and store the frames it keeps in
        one batch. Per item: the new memory's id, the reason it was dropped, or None for a
        replay."""
        frames = [x for _, x in items if isinstance(x, Frame)]
        emb = self.mem.embedder.embed_images([f.image for f in frames]) if frames else None
        out: list[int | str | None] = []
        keep: list[int] = []
        j = 0
        for name, x in items:
            kf = self.lane(name).keyframer
            if isinstance(x, Replay):
                kf.post(x.embedding)
                out.append(None)
                continue
            assert emb is not None
            reason = kf.post(emb[j])
            if reason is None:
                keep.append(j)
                out.append(len(keep) - 1)  # an index into the kept frames, replaced by its id below
            else:
                out.append(reason)
            j += 1
        if not keep:
            return out
        assert emb is not None
        ids = self.mem.add_frames([frames[i] for i in keep], embeddings=emb[keep], text=self.text)
        return [ids[o] if isinstance(o, int) else o for o in out]
