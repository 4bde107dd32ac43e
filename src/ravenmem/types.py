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

# ---------------------------------------------------------------- the ranges of every stored value
# Checked at the door (`Frame.check`, which `Memory.add_frames` runs; the HTTP and MCP models and
# the sources use the same functions), so that one absurd value is a one-line error for its
# sender instead of a stored row that breaks every later read (a time `fmt_time` cannot print, a
# thumbnail name too long for the file system, a distance that overflows).
T_MIN = 0.0  # 1970-01-01T00:00:00Z: Unix seconds; a simulator's clock that starts at 0 fits
T_MAX = 4_102_444_800.0  # 2100-01-01T00:00:00Z
MAX_COORD = 1e7  # metres from the map origin: 10,000 km holds any map on Earth (UTM included)
MAX_ANGLE = 1e6  # radians: an unwrapped heading of a robot that turned 160,000 times
MAX_ID = 2**63 - 1  # memory ids and frame indices: SQLite's INTEGER
MIN_IMAGE_SIDE = 2  # pixels: the smallest picture an embedder can crop and resize
MAX_SOURCE = 200  # characters of a source (camera) name
RANGES = {
    "t": f"Unix seconds from {T_MIN:.0f} (1970-01-01) to {T_MAX:.0f} (2100-01-01)",
    "coordinate": f"metres within +-{MAX_COORD:g} of the map origin",
    "angle": f"radians within +-{MAX_ANGLE:g}",
    "id": f"a whole number from 0 to {MAX_ID}",
}


def check_time(t: object, what: str = "t") -> float:
    """`t` as Unix seconds within [T_MIN, T_MAX], or a one-line InputError naming `what`."""
    v = _number(t, what)
    if not T_MIN <= v <= T_MAX:
        raise InputError(f"{what}: {t!r} is out of range ({RANGES['t']})")
    return v


def check_coord(v: object, what: str = "coordinate") -> float:
    """A position in metres within +-MAX_COORD, or a one-line InputError naming `what`."""
    f = _number(v, what)
    if not abs(f) <= MAX_COORD:
        raise InputError(f"{what}: {v!r} is out of range ({RANGES['coordinate']})")
    return f


def check_id(v: object, what: str = "memory id") -> int:
    """A memory id (or frame index): a whole number from 0 to MAX_ID (SQLite's INTEGER); a
    whole number written as text (a query string's) is read as one."""
    if type(v) is int and 0 <= v <= MAX_ID:  # the common case, decided at once
        return v
    if isinstance(v, str) and v.strip().lstrip("+-").isdigit():
        v = int(v)
    if isinstance(v, bool) or not isinstance(v, (int, np.integer, float, np.floating)):
        raise InputError(f"{what}: expected {RANGES['id']}, got {v!r}")
    if isinstance(v, (float, np.floating)) and not (math.isfinite(v) and float(v).is_integer()):
        raise InputError(f"{what}: expected {RANGES['id']}, got {v!r}")
    if not 0 <= int(v) <= MAX_ID:
        raise InputError(f"{what}: {v!r} is out of range ({RANGES['id']})")
    return int(v)


def check_picture(image: object, what: str = "image") -> np.ndarray:
    """An RGB uint8 (H, W, 3) array at least MIN_IMAGE_SIDE pixels on each side."""
    if not isinstance(image, np.ndarray) or image.ndim != 3 or image.shape[2] != 3 or image.dtype != np.uint8:
        got = f"{image.dtype} {image.shape}" if isinstance(image, np.ndarray) else type(image).__name__
        raise InputError(f"{what}: expected an RGB uint8 picture (height, width, 3), got {got}")
    h, w = image.shape[:2]
    if min(h, w) < MIN_IMAGE_SIDE:
        raise InputError(f"{what}: {w}x{h} pixels is too small (at least {MIN_IMAGE_SIDE}x{MIN_IMAGE_SIDE})")
    return image


def _number(v: object, what: str) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float, np.integer, np.floating)):
        raise InputError(f"{what}: expected a number, got {v!r}")
    try:
        f = float(v)
    except OverflowError:  # an int beyond float
        raise InputError(f"{what}: {v!r} is out of range") from None
    if not math.isfinite(f):
        raise InputError(f"{what}: {v!r} is not a finite number")
    return f


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
        c, a = MAX_COORD, MAX_ANGLE  # NaN fails every comparison, so this passes only good poses
        if -c <= self.x <= c and -c <= self.y <= c and -c <= self.z <= c and -a <= self.yaw <= a:
            q = self.quat
            if q is None or math.isfinite(q[0] + q[1] + q[2] + q[3]):  # a record read back: at once
                return
        vals = (self.x, self.y, self.z, self.yaw, *(self.quat or ()))
        if not all(math.isfinite(v) for v in vals):
            raise InputError(f"pose has a non-finite value: {self}")
        if max(abs(self.x), abs(self.y), abs(self.z)) > MAX_COORD or abs(self.yaw) > MAX_ANGLE:
            raise InputError(
                f"pose {self.xyz} yaw {self.yaw:g}: out of range ({RANGES['coordinate']}; "
                f"yaw {RANGES['angle']})"
            )

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

    def check(self) -> None:
        """What a memory accepts (the ranges at the top of this module): an RGB uint8 picture at
        least MIN_IMAGE_SIDE pixels a side, a pose, a time from T_MIN to T_MAX, a frame index
        from 0 to MAX_ID and a source name of at most MAX_SOURCE characters; a one-line
        InputError naming the frame otherwise."""
        name = f"frame {str(self.source)[:MAX_SOURCE]}#{self.index}"
        check_picture(self.image, f"{name}: image")
        if self.pose is None:
            raise InputError(f"{name}: no pose")
        if not isinstance(self.pose, Pose):
            raise InputError(f"{name}: pose must be a Pose, got {type(self.pose).__name__}")
        check_time(self.t, f"{name}: t")
        check_id(self.index, f"{name}: frame index")
        if not isinstance(self.source, str) or len(self.source) > MAX_SOURCE:
            raise InputError(f"{name}: source must be a name of at most {MAX_SOURCE} characters")


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
    `supported` says whether a text hit's score reaches above what things that are not there
    reach (`ravenmem.agent.support`, the rule `ask` declines by); None where nobody judged it.
    """

    memory: MemoryRecord
    score: float | None = None
    distance: float | None = None
    ocr_match: bool = False
    count: int = 1
    span: tuple[float, float] | None = None
    supported: bool | None = None


@dataclass(frozen=True)
class Region:
    """A planar disc (x, y, radius in metres), the region filter all tools accept."""

    x: float
    y: float
    r: float

    def __post_init__(self) -> None:
        check_coord(self.x, "region x")
        check_coord(self.y, "region y")
        r = _number(self.r, "region radius")
        if not 0 <= r <= 4 * MAX_COORD:
            raise InputError(f"region radius: {self.r!r} must be from 0 to {4 * MAX_COORD:g} m")


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
