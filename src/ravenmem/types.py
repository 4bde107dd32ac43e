"""Typed records shared by every part of ravenmem.

Data flows one way: a source yields `Frame`s, the keyframer keeps some, the embedder turns them
into vectors, the store keeps `MemoryRecord`s, and the retrieval tools return `Hit`s.
Timestamps are always float seconds since the Unix epoch, UTC: nothing here depends on the
local time zone of the machine that recorded or reads the memory.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from .errors import InputError


def yaw_of(qx: float, qy: float, qz: float, qw: float) -> float:
    """The heading (rad, the rotation about +z) of a unit quaternion (x, y, z, w)."""
    return math.atan2(2.0 * (qw * qz + qx * qy), 1.0 - 2.0 * (qy * qy + qz * qz))


@dataclass(frozen=True)
class Pose:
    """A camera pose in the map frame: position in metres, heading (yaw) in radians.

    The full orientation quaternion (x, y, z, w) is kept when the source gives one, because
    yaw alone loses pitch and roll that a user may want back (e.g. a hand-held camera).
    """

    x: float
    y: float
    z: float = 0.0
    yaw: float = 0.0
    quat: tuple[float, float, float, float] | None = None

    def __post_init__(self) -> None:
        vals = (self.x, self.y, self.z, self.yaw, *(self.quat or ()))
        if not all(math.isfinite(v) for v in vals):
            raise InputError(f"pose has a non-finite value: {self}")

    @classmethod
    def from_quaternion(
        cls, x: float, y: float, z: float, qx: float, qy: float, qz: float, qw: float
    ) -> Pose:
        """Build a pose from a position and a quaternion; yaw is the rotation about +z."""
        n = math.sqrt(qx * qx + qy * qy + qz * qz + qw * qw)
        if not math.isfinite(n) or n < 1e-9:
            raise InputError(f"quaternion has zero or non-finite norm: {(qx, qy, qz, qw)}")
        qx, qy, qz, qw = qx / n, qy / n, qz / n, qw / n
        return cls(x, y, z, yaw_of(qx, qy, qz, qw), (qx, qy, qz, qw))

    @property
    def xyz(self) -> tuple[float, float, float]:
        return (self.x, self.y, self.z)

    def distance_to(self, other: Pose, planar: bool = False) -> float:
        dz = 0.0 if planar else self.z - other.z
        return math.sqrt((self.x - other.x) ** 2 + (self.y - other.y) ** 2 + dz * dz)

    def rotation_to(self, other: Pose) -> float:
        """Angle (rad) between the two orientations: full 3-D when both have quaternions, else yaw."""
        if self.quat is not None and other.quat is not None:
            dot = abs(sum(p * q for p, q in zip(self.quat, other.quat)))
            return 2.0 * math.acos(min(1.0, dot))
        return abs((other.yaw - self.yaw + math.pi) % (2.0 * math.pi) - math.pi)


@dataclass(frozen=True)
class Intrinsics:
    """Pinhole camera intrinsics in pixels for an image `width` x `height` (0 x 0 = not known
    yet: `for_image` fills them in from the first image). Shared by simulators, sources and
    the mapper, so it lives with the other records."""

    fx: float
    fy: float
    cx: float
    cy: float
    width: int = 0
    height: int = 0

    def __post_init__(self) -> None:
        vals = (self.fx, self.fy, self.cx, self.cy)
        if not all(math.isfinite(v) for v in vals) or self.fx <= 0 or self.fy <= 0:
            raise InputError(f"bad camera intrinsics: fx, fy must be > 0 and all finite: {self}")
        if self.width < 0 or self.height < 0:
            raise InputError(f"bad camera intrinsics: negative image size: {self}")

    @classmethod
    def from_fov(cls, width: int, height: int, hfov_deg: float) -> Intrinsics:
        """Square pixels and a horizontal field of view: what simulators usually state."""
        if width <= 0 or height <= 0 or not 0.0 < hfov_deg < 180.0:
            raise InputError(f"bad camera: width={width}, height={height}, hfov_deg={hfov_deg}")
        f = (width / 2.0) / math.tan(math.radians(hfov_deg) / 2.0)
        return cls(f, f, width / 2.0, height / 2.0, width, height)

    @property
    def hfov(self) -> float:
        """Horizontal field of view in radians."""
        return 2.0 * math.atan2(self.width / 2.0, self.fx)

    def for_image(self, width: int, height: int) -> Intrinsics:
        """These intrinsics for an image of `width` x `height`: the size is filled in when it was
        not known, and the camera scaled when the image is a uniformly resized version of the
        calibrated one (e.g. a 320x240 depth image of a 640x480 calibration)."""
        if (self.width, self.height) == (width, height):
            return self
        if self.width == 0 or self.height == 0:
            return replace(self, width=width, height=height)
        sx, sy = width / self.width, height / self.height
        if abs(sx - sy) > 1e-6:
            raise InputError(
                f"image is {width}x{height} but the camera was calibrated at {self.width}x{self.height} "
                "(not a uniform resize)"
            )
        return Intrinsics(self.fx * sx, self.fy * sy, self.cx * sx, self.cy * sy, width, height)


@dataclass
class Frame:
    """One decoded frame from a source, before keyframing.

    `image` is an RGB uint8 array (H, W, 3). `depth` (metres, float32 H x W) is set by sources
    that have it (simulators, RGB-D bags) and is used by the mapper, never stored in memory.
    `pose` may be None when a source has no pose for this frame; such frames are skipped and
    counted by the ingest pipeline rather than guessed.
    """

    image: np.ndarray
    t: float
    pose: Pose | None
    source: str = ""
    index: int = 0
    depth: np.ndarray | None = None
    path: str | None = None  # the image file, when the source reads one (kept if thumbnails are off)


@dataclass
class MemoryRecord:
    """One stored memory: where and when the robot saw what.

    `id` is assigned by the store (increasing with insertion order). `embedding` is filled only
    when asked for (stores return records without vectors by default, to keep results light).
    `image_path` is relative to the memory folder (a JPEG thumbnail) or an absolute path to the
    original frame; None when thumbnails are off and the source is not a file.
    """

    id: int
    t: float
    pose: Pose
    source: str = ""
    frame_index: int = 0
    image_path: str | None = None
    ocr_text: str = ""
    embedding: np.ndarray | None = field(default=None, repr=False)

    def with_id(self, new_id: int) -> MemoryRecord:
        return replace(self, id=new_id)


@dataclass
class Hit:
    """A retrieval result: a memory plus why it was returned.

    `score` is the similarity (cosine for text/image tools, fused with OCR when that channel
    matched); `distance` is metres for the position tool. Tools fill the one that applies.
    `count` and `span` say what a consolidated memory stands for (`ravenmem consolidate`): how
    many memories it represents and the (first, last) time they were seen; 1 and None otherwise.
    """

    memory: MemoryRecord
    score: float | None = None
    distance: float | None = None
    ocr_match: bool = False
    count: int = 1
    span: tuple[float, float] | None = None


@dataclass(frozen=True)
class Region:
    """A planar disc (x, y, radius in metres), the region filter all tools accept."""

    x: float
    y: float
    r: float


@dataclass(frozen=True)
class Filter:
    """Filters every retrieval tool accepts: a time window [after, before] and a region."""

    after: float | None = None
    before: float | None = None
    region: Region | None = None

    def accepts(self, rec: MemoryRecord) -> bool:
        if self.after is not None and rec.t < self.after:
            return False
        if self.before is not None and rec.t > self.before:
            return False
        if self.region is not None:
            dx, dy = rec.pose.x - self.region.x, rec.pose.y - self.region.y
            if dx * dx + dy * dy > self.region.r * self.region.r:
                return False
        return True

    @property
    def empty(self) -> bool:
        return self.after is None and self.before is None and self.region is None
