"""ROS message conversion shared by the bag source, the live robot link and the services.

One place turns ROS messages (as `rosbags` deserialises them, from a bag or from CDR bytes off
the wire) into what ravenmem stores, and back: images into RGB arrays, pose messages and TF
transforms into (time, position, quaternion) samples, and plain dicts (the JSON of a goal's
`geometry_msgs/PoseStamped`, built once by `ravenmem.nav.goals.pose_stamped`; a service reply)
into messages and CDR bytes (`to_message`, `serialize`). A message that cannot be used gives a
skip reason (a string) rather than an exception, so every caller counts its drops the same way.
Types other than the ones `rosbags` knows (tf2_msgs, the `ravenmem_msgs` services, Nav2's
action) are registered from their interface text (`register`).
"""

from __future__ import annotations

import io
import math
import re
from collections.abc import Iterator
from functools import cache
from typing import Any, NamedTuple

import numpy as np
from PIL import Image, UnidentifiedImageError
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from ..ingest.common import pil_to_rgb

IMAGE = "sensor_msgs/msg/Image"
COMPRESSED = "sensor_msgs/msg/CompressedImage"
ODOMETRY = "nav_msgs/msg/Odometry"
POSE_STAMPED = "geometry_msgs/msg/PoseStamped"
POSE_COV = "geometry_msgs/msg/PoseWithCovarianceStamped"
POSE_TYPES = (ODOMETRY, POSE_STAMPED, POSE_COV)
TF = "tf2_msgs/msg/TFMessage"
IMAGE_TYPES = (IMAGE, COMPRESSED)

# short names users may write instead of the full ROS 2 type name
SHORT_NAMES = {t.rsplit("/", 1)[1].lower(): t for t in (*IMAGE_TYPES, *POSE_TYPES, TF)} | {"tf": TF}

SKIP_DECODE = "undecodable message"
SKIP_MALFORMED = "malformed image message"
SKIP_COMPRESSED = "undecodable compressed image"
_CHANNELS = {"rgb8": 3, "bgr8": 3, "rgba8": 4, "bgra8": 4, "mono8": 1, "mono16": 1}


class Sample(NamedTuple):
    """One pose sample: time (s), position (m) and unit quaternion (x, y, z, w)."""

    t: float
    xyz: tuple[float, float, float]
    quat: tuple[float, float, float, float]


class TfSample(NamedTuple):
    """One transform of a TF message: `child`'s pose in `parent` at time t."""

    parent: str
    child: str
    t: float
    xyz: tuple[float, float, float]
    quat: tuple[float, float, float, float]


@cache
def typestore(ros1: bool = False) -> Any:
    """The rosbags type store for ROS 2 (Humble) or ROS 1 (Noetic), with tf2_msgs/TFMessage known."""
    ts = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    if TF not in ts.types:
        ts.register(get_types_from_msg("geometry_msgs/TransformStamped[] transforms", TF))
    return ts


def type_name(name: str) -> str | None:
    """The full ROS 2 type of a short or full name ('Odometry', 'nav_msgs/msg/Odometry',
    'nav_msgs/Odometry'), or None when it is not a type ravenmem reads."""
    s = name.strip()
    if s.lower() in SHORT_NAMES:
        return SHORT_NAMES[s.lower()]
    if s.count("/") == 1:
        pkg, msg = s.split("/")
        s = f"{pkg}/msg/{msg}"
    return s if s in (*IMAGE_TYPES, *POSE_TYPES, TF) else None


_DDS_TYPE = re.compile(r"(\w+)::msg::dds_::(\w+?)_$")


def type_from_key(key: str) -> str | None:
    """The ROS 2 type named inside an rmw_zenoh key expression, e.g.
    `0/odom/nav_msgs::msg::dds_::Odometry_/RIHS01_...` -> `nav_msgs/msg/Odometry`, else None."""
    for part in key.split("/"):
        m = _DDS_TYPE.fullmatch(part)
        if m:
            return f"{m.group(1)}/msg/{m.group(2)}"
    return None


def decode_image(msg: Any, msgtype: str) -> np.ndarray | str:
    """RGB uint8 from an Image/CompressedImage message, or the skip reason."""
    if msgtype == COMPRESSED:
        fmt = str(msg.format).lower()
        if "compresseddepth" in fmt:
            return "compressed depth image"
        try:
            with Image.open(io.BytesIO(np.asarray(msg.data, dtype=np.uint8).tobytes())) as im:
                return pil_to_rgb(im)
        except (UnidentifiedImageError, OSError, ValueError, SyntaxError, Image.DecompressionBombError):
            return SKIP_COMPRESSED
    enc = str(msg.encoding).lower()
    if enc not in _CHANNELS:
        return f"unsupported encoding {msg.encoding!r}"
    h, w, step, ch = int(msg.height), int(msg.width), int(msg.step), _CHANNELS[enc]
    bpp = 2 if enc == "mono16" else ch
    data = np.asarray(msg.data, dtype=np.uint8).reshape(-1)
    if h <= 0 or w <= 0 or step < w * bpp or data.size < h * step:
        return SKIP_MALFORMED
    rows = data[: h * step].reshape(h, step)[:, : w * bpp]
    if enc == "mono16":
        v = np.ascontiguousarray(rows).view(">u2" if msg.is_bigendian else "<u2").astype(np.float64)
        g = (v * (255.0 / max(float(v.max()), 1.0))).astype(np.uint8)
        return np.repeat(g[:, :, None], 3, axis=2)
    img = rows.reshape(h, w, ch)
    if ch == 1:
        return np.repeat(img, 3, axis=2)
    if enc.startswith("bgr"):
        img = img[:, :, 2::-1]
    return np.array(img[:, :, :3])  # a writable copy, independent of the message buffer


def raw_image_bytes(msg: Any, msgtype: str) -> int:
    """Size of the frame as raw RGB (for the compression figures); 0 when unknown before decoding."""
    return int(msg.height) * int(msg.width) * 3 if msgtype == IMAGE else 0


def header_time(msg: Any) -> float | None:
    """header.stamp in seconds, or None when the message has no header or a zero stamp."""
    header = getattr(msg, "header", None)
    if header is None:
        return None
    s = int(header.stamp.sec) + int(header.stamp.nanosec) * 1e-9
    return s if s > 0 else None


def stamp(msg: Any, fallback: float, use_header: bool = True) -> float:
    """The message's header stamp (when asked for and non-zero), else `fallback` (receive time)."""
    t = header_time(msg) if use_header else None
    return fallback if t is None else t


def _quat(q: Any) -> tuple[float, float, float, float] | None:
    v = (float(q.x), float(q.y), float(q.z), float(q.w))
    if not all(math.isfinite(c) for c in v) or math.sqrt(sum(c * c for c in v)) < 1e-9:
        return None
    return v


def pose_of(
    msg: Any, msgtype: str
) -> tuple[tuple[float, float, float], tuple[float, float, float, float]] | None:
    """Position and orientation of an Odometry/PoseStamped/PoseWithCovarianceStamped message,
    or None when its quaternion is zero or not finite (or the position is not finite)."""
    p = msg.pose if msgtype == POSE_STAMPED else msg.pose.pose
    q = _quat(p.orientation)
    xyz = (float(p.position.x), float(p.position.y), float(p.position.z))
    if q is None or not all(math.isfinite(c) for c in xyz):
        return None
    return xyz, q


def tf_samples(msg: Any, fallback: float, use_header: bool = True) -> Iterator[TfSample]:
    """The usable transforms of a TFMessage (unusable rotations are left out)."""
    for tfm in msg.transforms:
        tr = tfm.transform.translation
        q = _quat(tfm.transform.rotation)
        xyz = (float(tr.x), float(tr.y), float(tr.z))
        if q is None or not all(math.isfinite(c) for c in xyz):
            continue
        yield TfSample(tfm.header.frame_id, tfm.child_frame_id, stamp(tfm, fallback, use_header), xyz, q)


def register(definitions: dict[str, str]) -> None:
    """Teach the type store `{type name: .msg text}` (types it knows already are left alone)."""
    ts = typestore()
    new = {}
    for name, text in definitions.items():
        if (
            name not in ts.types
        ):  # keyed by the name given (rosbags would file srv types under .../srv/msg/...)
            new[name] = next(iter(get_types_from_msg(text, name).values()))
    if new:
        ts.register(new)


def to_message(data: Any, msgtype: str) -> Any:
    """A message of `msgtype` from a plain dict (nested dicts for nested messages, lists for
    arrays; fields left out take their zero value), e.g. `nav.goals.pose_stamped(...)`."""
    ts = typestore()
    cls = ts.types[msgtype]
    fields = ts.fielddefs[msgtype][1]
    values = {}
    given = data if isinstance(data, dict) else {}
    for name, (kind, spec) in fields:
        values[name] = _field(ts, kind, spec, given.get(name))
    return cls(**values)


_ZERO = {"bool": False, "string": "", "wstring": ""}
_NUMPY = {"uint8": np.uint8, "int8": np.int8, "octet": np.uint8, "char": np.uint8, "byte": np.uint8}


def _field(ts: Any, kind: int, spec: Any, value: Any) -> Any:
    """One field's value for the message class (rosbags' field kinds: 1 base, 2 name, 3 array, 4 sequence)."""
    if kind == 1:  # a base type: (type name, string bound)
        base = spec[0]
        if value is None:
            return _ZERO.get(base, 0.0 if base.startswith("float") else 0)
        return str(value) if base in ("string", "wstring") else value
    if kind == 2:  # a nested message
        return to_message(value if value is not None else {}, spec)
    # arrays (3) and sequences (4): ((element kind, element spec), length)
    (ekind, espec), length = spec
    items = list(value or [])
    if kind == 3 and not items:
        items = [None] * int(length)
    if ekind == 1 and espec[0] in _NUMPY:
        return np.asarray([0 if v is None else v for v in items], _NUMPY[espec[0]])
    if ekind == 1 and espec[0] not in ("string", "wstring", "bool"):
        dtype = np.float64 if espec[0] == "float64" else np.float32 if espec[0] == "float32" else np.int64
        return np.asarray([_field(ts, 1, espec, v) for v in items]).astype(dtype)
    return [_field(ts, ekind, espec, v) for v in items]


def to_dict(msg: Any) -> Any:
    """A message as plain dicts and lists (byte arrays as bytes), the inverse of `to_message`."""
    if isinstance(msg, np.ndarray):
        return msg.tobytes() if msg.dtype == np.uint8 else msg.tolist()
    if isinstance(msg, (list, tuple)):
        return [to_dict(v) for v in msg]
    fields = getattr(msg, "__dataclass_fields__", None)
    if fields is None:
        return msg
    return {name: to_dict(getattr(msg, name)) for name in fields if name != "__msgtype__"}


def serialize(msg: Any, msgtype: str) -> bytes:
    """CDR bytes (with the 4-byte encapsulation header) of a ROS 2 message, as DDS/Zenoh carry it."""
    return bytes(typestore().serialize_cdr(msg, msgtype))


def deserialize(raw: bytes | memoryview, msgtype: str) -> Any:
    """A ROS 2 message from CDR bytes; rosbags checks the size, so a wrong type raises."""
    return typestore().deserialize_cdr(raw, msgtype)
