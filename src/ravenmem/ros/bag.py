"""ROS 1 bags, ROS 2 bags (sqlite3 or MCAP storage) and bare .mcap/.db3 files, via `rosbags`.

Two passes, both streaming: the pose messages (small) are read first into a `PoseTrack`, then
image messages are decoded one at a time and posed by interpolation at their timestamp.
Images: sensor_msgs/Image (rgb8, bgr8, rgba8, bgra8, mono8, mono16) and CompressedImage (any
format PIL decodes: jpeg, png, ...). Poses: nav_msgs/Odometry, geometry_msgs/PoseStamped,
geometry_msgs/PoseWithCovarianceStamped, or /tf (+ /tf_static) from `tf_parent` to `tf_child`.
Times come from header.stamp (`time_source="header"`, falling back to the time the bag received
the message when a stamp is zero) or from that receive time (`time_source="receive"`). The pose
options are named as the live link's (`ravenmem.ros.link.LinkConfig`): `tf_parent`, `tf_child`,
`time_source`, `pose_match`, `max_gap`.

`frame_id` is the frame the poses are in (REP 105): the TF parent, or the pose messages'
`header.frame_id`; `map` when they name none. Ingest records it (and a map identity derived
from the bag) in the memory, see `ravenmem.memory.anchor`.

Depth (for maps): `depth_topic` (sensor_msgs/Image, 16UC1 in mm or 32FC1 in m; by default the
one other image topic with "depth" in its name) is paired with each colour frame by time
(nearest within `depth_max_gap` s, streaming: a few depth images are held at once). The
depth camera's intrinsics come from its `camera_info` topic (by default the CameraInfo in the
depth topic's namespace, or the only one), else from `intrinsics=`. The camera's mount on
the posed frame comes from /tf_static when it links the pose's frame to the camera_info's
frame; a frame named `*optical*` is the optical frame itself, any other camera frame is a
REP-103 body frame (x forward, z up).
"""

from __future__ import annotations

from collections import deque
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
from rosbags.highlevel import AnyReader
from rosbags.typesys import Stores, get_typestore
from scipy.spatial.transform import Rotation

from ..errors import InputError
from ..ingest.base import SOURCES, SourceConfig, SourceStats
from ..ingest.common import check_gap, check_intrinsics, existing
from ..ingest.depth import camera_info_intrinsics, decode_depth_message
from ..ingest.identity import file_head, make_identity
from ..ingest.poses import PoseTrack, check_match_mode
from ..types import Frame, Intrinsics
from . import msgs
from .msgs import IMAGE, IMAGE_TYPES, POSE_TYPES, SKIP_DECODE, TF, decode_image
from .tf import TfTree, check_time_source, norm_frame

CAMERA_INFO = "sensor_msgs/msg/CameraInfo"
# The optical frame (x right, y down, z forward) in a REP-103 camera body frame (x forward, z up).
_OPTICAL_IN_BODY = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


def _stamp(msg: Any, bag_ns: int, time_source: str) -> float:
    return msgs.stamp(msg, bag_ns * 1e-9, use_header=time_source == "header")


def _frame_of(msg: Any) -> str:
    header = getattr(msg, "header", None)
    return norm_frame(str(getattr(header, "frame_id", "") or ""))


def _pick(kind: str, available: dict[str, str], wanted: str | None, option: str) -> str:
    listing = ", ".join(f"{t} ({m})" for t, m in sorted(available.items())) or "none"
    if wanted is not None:
        if wanted not in available:
            raise InputError(f"{kind} topic {wanted!r} not in the bag; {kind} topics: {listing}")
        return wanted
    if len(available) != 1:
        what = "no" if not available else "several"
        raise InputError(f"bag has {what} {kind} topics ({listing}); choose one with {option}=TOPIC")
    return next(iter(available))


@dataclass
class RosbagConfig(SourceConfig):
    """A ROS bag (`rosbag:PATH`; see the module docstring). image_topic / pose_topic: which
    topics (default: the only one of its kind; /tf when there is no pose topic); tf_parent /
    tf_child: the TF frames posed; time_source `header` or `receive`; pose_match `interpolate` or
    `nearest` (within max_gap s, 0.05 when not given); depth_topic, camera_info_topic,
    depth_max_gap (s) and intrinsics: depth for the map."""

    image_topic: str | None = None
    pose_topic: str | None = None
    tf_parent: str | None = None
    tf_child: str = "base_link"
    time_source: str = "header"
    pose_match: str = "interpolate"
    max_gap: float | None = None
    depth_topic: str | None = None
    camera_info_topic: str | None = None
    depth_max_gap: float = 0.05
    intrinsics: Intrinsics | str | None = None

    kind: ClassVar[str] = "rosbag"

    def __post_init__(self) -> None:
        check_time_source(self.time_source, "rosbag")
        check_match_mode(self.pose_match)
        self.max_gap = check_gap("rosbag", "max_gap", self.max_gap)
        if self.pose_match == "nearest" and self.max_gap is None:
            self.max_gap = 0.05
        self.depth_max_gap = check_gap("rosbag", "depth_max_gap", self.depth_max_gap) or 0.0
        self.intrinsics = check_intrinsics(self.intrinsics)


class RosbagSource:
    """Frames from one image topic of a bag, posed from one pose topic or the TF tree
    (options: `RosbagConfig`)."""

    def __init__(self, path: str | Path | RosbagConfig, **options: Any) -> None:
        cfg = self.config = RosbagConfig.of(path, **options)
        self.path = existing(cfg.path, "ROS bag")
        self.name = f"rosbag:{self.path.name}"
        self.stats = SourceStats()
        self.time_source = cfg.time_source
        self.frame_id = "map"
        self.pose_match = check_match_mode(cfg.pose_match)
        self.max_gap = cfg.max_gap
        image_topic, pose_topic, depth_topic = cfg.image_topic, cfg.pose_topic, cfg.depth_topic
        tf_parent, tf_child, camera_info_topic = cfg.tf_parent, cfg.tf_child, cfg.camera_info_topic
        with self._reader() as reader:
            topics = {c.topic: c.msgtype for c in reader.connections}
            images = {t: m for t, m in topics.items() if m in IMAGE_TYPES}
            colour = {t: m for t, m in images.items() if "depth" not in t.lower()} or images
            self.image_topic = _pick("image", images if image_topic else colour, image_topic, "image_topic")
            counts = [c.msgcount for c in reader.connections if c.topic == self.image_topic]
            self.frame_count: int | None = sum(counts) if all(n > 0 for n in counts) else None
            self.depth_topic = self._depth_topic(images, depth_topic)
            tf_topics = [t for t, m in topics.items() if m == TF]
            poses = {t: m for t, m in topics.items() if m in POSE_TYPES}
            if pose_topic is None and not poses and tf_topics:
                pose_topic = "/tf"
            if pose_topic is not None and topics.get(pose_topic) == TF:
                self.pose_topic = pose_topic
                self.track = self._tf_track(reader, tf_topics, tf_parent, tf_child)
            else:
                self.pose_topic = _pick("pose", poses | {t: TF for t in tf_topics}, pose_topic, "pose_topic")
                self.track = self._pose_track(reader, self.pose_topic)
            self.depth_max_gap = cfg.depth_max_gap
            self.intrinsics: Intrinsics | None = cfg.intrinsics  # type: ignore[assignment]
            self.camera_extrinsic: np.ndarray | str = "body"
            if self.depth_topic is not None:
                self._camera(reader, topics, camera_info_topic, tf_topics, tf_child)

    def _depth_topic(self, images: dict[str, str], wanted: str | None) -> str | None:
        if wanted is not None:
            if images.get(wanted) != IMAGE:
                listing = ", ".join(t for t, m in sorted(images.items()) if m == IMAGE) or "none"
                raise InputError(
                    f"depth topic {wanted!r} is not a sensor_msgs/Image topic of the bag ({listing})"
                )
            return wanted
        cands = [
            t for t, m in images.items() if m == IMAGE and "depth" in t.lower() and t != self.image_topic
        ]
        return cands[0] if len(cands) == 1 else None

    def _camera(
        self,
        reader: AnyReader,
        topics: dict[str, str],
        info_topic: str | None,
        tf_topics: list[str],
        child: str,
    ) -> None:
        """Intrinsics from the depth camera's CameraInfo, and its mount from /tf_static."""
        infos = sorted(t for t, m in topics.items() if m == CAMERA_INFO)
        if info_topic is None:
            assert self.depth_topic is not None
            ns = self.depth_topic.rsplit("/", 1)[0]
            same = [t for t in infos if t.rsplit("/", 1)[0] == ns]
            info_topic = same[0] if same else (infos[0] if len(infos) == 1 else None)
        elif info_topic not in infos:
            raise InputError(
                f"camera_info topic {info_topic!r} not in the bag (CameraInfo topics: {infos or 'none'})"
            )
        self.camera_info_topic = info_topic
        if info_topic is None:
            return
        conns = [c for c in reader.connections if c.topic == info_topic]
        cam_frame = ""
        for conn, _, raw in reader.messages(connections=conns):
            try:
                msg: Any = reader.deserialize(raw, conn.msgtype)
                intr = camera_info_intrinsics(msg)
            except Exception:
                continue
            self.intrinsics = self.intrinsics or intr
            cam_frame = norm_frame(str(msg.header.frame_id))
            break
        self.camera_extrinsic = self._mount(reader, tf_topics, norm_frame(child), cam_frame)

    def _mount(self, reader: AnyReader, tf_topics: list[str], child: str, cam: str) -> np.ndarray | str:
        """The optical camera in the posed frame: a static /tf chain child -> camera frame."""
        optical = "optical" in cam
        if not cam or cam == child:
            return "optical" if optical else "body"
        edges: dict[str, tuple[str, np.ndarray]] = {}  # frame -> (parent, 4x4 parent_T_frame)
        conns = [c for c in reader.connections if c.topic in tf_topics and c.topic.endswith("tf_static")]
        for conn, _, raw in reader.messages(connections=conns):
            try:
                msg: Any = reader.deserialize(raw, conn.msgtype)
            except Exception:
                continue
            for tfm in msg.transforms:
                tr, r = tfm.transform.translation, tfm.transform.rotation
                m = np.eye(4)
                m[:3, :3] = Rotation.from_quat([r.x, r.y, r.z, r.w]).as_matrix()
                m[:3, 3] = (tr.x, tr.y, tr.z)
                edges[norm_frame(tfm.child_frame_id)] = (norm_frame(tfm.header.frame_id), m)
        chain, f = np.eye(4), cam
        while f != child:
            if f not in edges or len(chain) > 64:
                return "optical" if optical else "body"  # not linked: assume the camera sits at the pose
            parent, m = edges[f]
            chain, f = m @ chain, parent
        if not optical:
            body = np.eye(4)
            body[:3, :3] = _OPTICAL_IN_BODY
            chain = chain @ body
        return chain

    def identity(self) -> str:
        """The bag's name and image topic, and the first MiB of its (first) storage file."""
        files = sorted(f for f in self.path.iterdir() if f.is_file()) if self.path.is_dir() else [self.path]
        data = [f for f in files if f.suffix in (".db3", ".mcap", ".bag")] or files
        head = file_head(data[0]) if data else b""
        return make_identity("rosbag", f"{self.path.name}{self.image_topic}", [self.image_topic, head])

    @contextmanager
    def _reader(self) -> Iterator[AnyReader]:
        is2 = self.path.is_dir() or self.path.suffix != ".bag"
        store = get_typestore(Stores.ROS2_HUMBLE if is2 else Stores.ROS1_NOETIC)
        try:
            reader = AnyReader([self.path], default_typestore=store)
            reader.open()
        except Exception as e:  # rosbags raises several unrelated types for unreadable bags
            raise InputError(f"{self.path}: not a readable ROS bag ({e})") from None
        try:
            yield reader
        finally:
            reader.close()

    def _pose_track(self, reader: AnyReader, topic: str) -> PoseTrack:
        conns = [c for c in reader.connections if c.topic == topic]
        t: list[float] = []
        xyz: list[tuple[float, float, float]] = []
        quat: list[tuple[float, float, float, float]] = []
        for conn, ns, raw in reader.messages(connections=conns):
            try:
                msg: Any = reader.deserialize(raw, conn.msgtype)
            except Exception:
                self.stats.skip(f"undecodable pose message on {topic}")
                continue
            pq = msgs.pose_of(msg, conn.msgtype)
            if pq is None:
                self.stats.skip(f"invalid pose message on {topic}")
                continue
            t.append(_stamp(msg, ns, self.time_source))
            if len(t) == 1:
                self.frame_id = _frame_of(msg) or self.frame_id
            xyz.append(pq[0])
            quat.append(pq[1])
        if not t:
            raise InputError(f"{self.path}: pose topic {topic!r} has no usable messages")
        return PoseTrack.from_samples(t, xyz, quat, name=f"{self.path}:{topic}")

    def _tf_track(self, reader: AnyReader, tf_topics: list[str], parent: str | None, child: str) -> PoseTrack:
        tree = TfTree()
        conns = [c for c in reader.connections if c.topic in tf_topics]
        for conn, ns, raw in reader.messages(connections=conns):
            try:
                msg: Any = reader.deserialize(raw, conn.msgtype)
            except Exception:
                self.stats.skip("undecodable tf message")
                continue
            static = conn.topic.endswith("tf_static")
            for tf in msgs.tf_samples(msg, ns * 1e-9, use_header=self.time_source == "header"):
                tree.add(tf.parent, tf.child, tf.t, tf.xyz, tf.quat, static=static)
        tree.require(child, str(self.path))
        if parent is None:
            parent = tree.default_parent(child)
            if parent is None:
                raise InputError(
                    f"{self.path}: no map/odom/world ancestor of {child!r} in /tf; set tf_parent and "
                    f"tf_child (frames: {', '.join(tree.frames) or 'none'})"
                )
        self.tf_frames = (parent, child)
        self.frame_id = norm_frame(parent)
        return tree.track(parent, child, name=str(self.path))

    def __iter__(self) -> Iterator[Frame]:
        self.stats = SourceStats()
        if self.depth_topic is None:
            yield from self._frames()
            return
        # Pair each colour frame with the nearest depth image by time, streaming: a colour
        # frame waits until a depth image later than it (or far past it) has arrived.
        depths: deque[tuple[float, np.ndarray]] = deque(maxlen=8)
        waiting: deque[Frame] = deque()
        gap = self.depth_max_gap

        def paired(f: Frame) -> Frame:
            best = min(depths, key=lambda d: abs(d[0] - f.t), default=None)
            if best is not None and abs(best[0] - f.t) <= gap:
                f.depth = best[1]
            return f

        for item in self._frames(with_depth=True):
            if isinstance(item, Frame):
                waiting.append(item)
            else:
                depths.append(item)
            now = item.t if isinstance(item, Frame) else item[0]
            while waiting and (
                waiting[0].t <= (depths[-1][0] if depths else -np.inf) or waiting[0].t < now - max(gap, 0.5)
            ):
                yield paired(waiting.popleft())
        while waiting:
            yield paired(waiting.popleft())

    def _frames(self, with_depth: bool = False) -> Iterator[Any]:
        """Posed colour frames in bag order; with `with_depth`, also (t, metres) depth images."""
        with self._reader() as reader:
            topics = {self.image_topic, self.depth_topic} if with_depth else {self.image_topic}
            conns = [c for c in reader.connections if c.topic in topics]
            index = -1
            for conn, ns, raw in reader.messages(connections=conns):
                if conn.topic == self.depth_topic and conn.topic != self.image_topic:
                    try:
                        dmsg: Any = reader.deserialize(raw, conn.msgtype)
                    except Exception:
                        continue
                    depth = decode_depth_message(dmsg)
                    if not isinstance(depth, str):
                        yield (_stamp(dmsg, ns, self.time_source), depth)
                    continue
                index += 1
                self.stats.frames_seen += 1
                try:
                    msg: Any = reader.deserialize(raw, conn.msgtype)
                except Exception:
                    self.stats.skip(SKIP_DECODE)
                    continue
                self.stats.raw_bytes += msgs.raw_image_bytes(msg, conn.msgtype)
                t = _stamp(msg, ns, self.time_source)
                pose = self.track.match(t, self.pose_match, self.max_gap)
                if isinstance(pose, str):
                    self.stats.skip(pose)
                    continue
                image = decode_image(msg, conn.msgtype)
                if isinstance(image, str):
                    self.stats.skip(image)
                    continue
                if conn.msgtype != IMAGE:
                    self.stats.raw_bytes += image.size
                self.stats.frames_yielded += 1
                yield Frame(image=image, t=t, pose=pose, source=str(self.path), index=index)


@SOURCES.register("rosbag")
def _rosbag(spec: str | RosbagConfig, **kwargs: Any) -> RosbagSource:
    return RosbagSource(RosbagConfig.of(spec, **kwargs))
