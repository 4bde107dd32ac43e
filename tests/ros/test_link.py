"""The robot link's logic without Zenoh: real CDR messages in, posed frames to a sink, goals out."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ravenmem.errors import InputError
from ravenmem.ingest.poses import SKIP_GAP, SKIP_OUTSIDE
from ravenmem.nav.base import PlanResult
from ravenmem.nav.goals import GoalPlan, pose_stamped, read_pose_stamped
from ravenmem.ros import msgs as rosmsg
from ravenmem.ros.link import SKIP_NO_POSE, SKIP_TYPE, LinkConfig, RosLink, goal_bytes, goal_of
from ravenmem.types import Pose
from tests.ros import ros_wire as w

POSE_TIMES = [9.95 + 0.1 * k for k in range(9)]  # 9.95 .. 10.75


class Recorder:
    """A sink that keeps what it was given and numbers it (the link's contract: id or reason)."""

    def __init__(self, refuse: set[int] | None = None) -> None:
        self.frames: list[tuple[np.ndarray, Pose, float]] = []
        self.refuse = refuse or set()
        self.calls = 0

    def __call__(self, image: np.ndarray, pose: Pose, t: float) -> int | str:
        self.calls += 1
        if self.calls in self.refuse:
            return "too little motion"
        self.frames.append((image, pose, t))
        return len(self.frames) - 1


class Clock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


def link(spec: str, sink: Recorder, clock: Clock | None = None) -> RosLink:
    c = clock or Clock()
    return RosLink(LinkConfig.from_spec(spec), sink, clock=lambda: 5000.0, monotonic=c)


def assert_pose(pose: Pose, x: float, y: float, yaw: float) -> None:
    assert (pose.x, pose.y, pose.z) == pytest.approx((x, y, 0.0), abs=1e-9)
    assert math.remainder(pose.yaw - yaw, 2 * math.pi) == pytest.approx(0.0, abs=1e-9)
    assert pose.quat is not None


def test_raw_and_compressed_images_with_odometry_are_posed_at_their_stamp() -> None:
    sink = Recorder()
    lk = link("image=/camera/color/image_raw,pose=/odom", sink)
    for t in POSE_TIMES:
        lk.pose("odom", w.odom(t))
    pics = [w.picture(i) for i in range(3)]
    lk.image("camera/color/image_raw", w.image(10.02, pics[0], "rgb8"))
    lk.image("camera/color/image_raw", w.image(10.31, pics[1], "bgr8"))
    lk.image("camera/color/image_raw", w.jpeg(10.5, pics[2]))  # same key, other type: found by decoding
    assert lk.stats.images == 3 and lk.stats.poses == len(POSE_TIMES)
    assert lk.stats.stored == 3 and lk.stats.skipped == {} and lk.stats.last_id == 2
    for (img, pose, t), want_t, pic in zip(sink.frames, (10.02, 10.31, 10.5), pics, strict=True):
        assert t == pytest.approx(want_t, abs=1e-9)
        assert_pose(pose, *w.motion(want_t))
        assert img.shape == pic.shape and img.dtype == np.uint8
    assert np.array_equal(sink.frames[0][0], pics[0]) and np.array_equal(sink.frames[1][0], pics[1])
    assert np.abs(sink.frames[2][0].astype(int) - pics[2]).mean() < 6  # JPEG, close to the original


def test_an_image_waits_for_the_pose_after_it_then_times_out() -> None:
    sink, clock = Recorder(), Clock()
    lk = link("image=cam,pose=odom,wait=0.5", sink, clock)
    lk.pose("odom", w.odom(10.0))
    lk.image("cam", w.image(10.05, w.picture(0)))
    assert lk.waiting == 1 and sink.calls == 0  # odometry lags: the image waits for 10.1
    lk.pose("odom", w.odom(10.1))
    assert lk.waiting == 0 and lk.stats.stored == 1
    assert_pose(sink.frames[0][1], *w.motion(10.05))
    lk.image("cam", w.image(10.2, w.picture(1)))
    clock.now += 0.4
    lk.tick()
    assert lk.waiting == 1
    clock.now += 0.2  # waited 0.6 s > wait: no later pose came
    lk.tick()
    assert lk.waiting == 0 and lk.stats.skipped == {SKIP_NO_POSE: 1} and lk.stats.stored == 1


def test_images_before_the_poses_gaps_and_bad_messages_are_counted() -> None:
    sink = Recorder(refuse={1})
    lk = link("image=cam,pose=odom,max_gap=0.15", sink)
    lk.image("cam", w.image(9.0, w.picture(0)))  # waits: no pose yet
    for t in (10.0, 10.1, 10.5, 10.6):  # a 0.4 s gap between 10.1 and 10.5
        lk.pose("odom", w.odom(t))
    lk.image("cam", w.image(10.3, w.picture(1)))  # inside the gap
    lk.image("cam", w.image(10.05, w.picture(2)))  # the sink refuses it (a keyframe rule)
    lk.image("cam", w.image(10.55, w.picture(3)))
    lk.image("cam", b"\x00\x01\x00\x00 not a message")
    lk.pose("odom", b"garbage")
    yuv = rosmsg.deserialize(w.image(10.56, w.picture(4)), rosmsg.IMAGE)
    yuv.encoding = "yuv422"
    lk.image("cam", rosmsg.serialize(yuv, rosmsg.IMAGE))
    assert lk.stats.skipped == {
        SKIP_OUTSIDE: 1,
        SKIP_GAP: 1,
        "too little motion": 1,
        SKIP_TYPE: 1,
        f"{SKIP_TYPE} on odom": 1,
        "unsupported encoding 'yuv422'": 1,
    }
    assert lk.stats.stored == 1 and [round(t, 3) for _, _, t in sink.frames] == [10.55]


def test_tf_chain_with_static_map_to_odom() -> None:
    sink = Recorder()
    lk = link("image=cam,pose=tf,tf_parent=map", sink)
    assert lk.cfg.tf and lk.cfg.tf_static_key == "tf_static"
    for t in POSE_TIMES[:3]:
        lk.pose("tf", w.tf(t))
    lk.image("cam", w.image(10.1, w.picture(0)))
    assert lk.waiting == 1  # odom -> base_link is known but map is not connected yet
    lk.pose("tf_static", w.tf_static())
    assert lk.waiting == 0 and lk.stats.stored == 1
    assert_pose(sink.frames[0][1], *w.in_map(10.1))


@pytest.mark.parametrize(("parent", "expect"), [("", w.in_map), (",tf_parent=odom", w.motion)])
def test_tf_parent_is_picked_once_or_given(parent: str, expect: object) -> None:
    sink = Recorder()
    lk = link("image=cam,pose=tf" + parent, sink)
    lk.pose("tf_static", w.tf_static())
    for t in POSE_TIMES[:3]:
        lk.pose("tf", w.tf(t))
    lk.image("cam", w.image(10.1, w.picture(0)))
    assert_pose(sink.frames[0][1], *expect(10.1))  # type: ignore[operator]
    assert lk.poses.parent == ("odom" if parent else "map")


def test_tf_parent_stays_once_chosen() -> None:
    sink = Recorder()
    lk = link("image=cam,pose=tf", sink)
    for t in POSE_TIMES[:3]:
        lk.pose("tf", w.tf(t))
    lk.image("cam", w.image(10.1, w.picture(0)))  # only odom known: odom it is, for the whole run
    lk.pose("tf_static", w.tf_static())
    lk.pose("tf", w.tf(POSE_TIMES[3]))
    lk.image("cam", w.image(10.2, w.picture(1)))
    assert lk.poses.parent == "odom"
    assert_pose(sink.frames[0][1], *w.motion(10.1))
    assert_pose(sink.frames[1][1], *w.motion(10.2))


def test_nearest_matching_and_receive_time() -> None:
    sink = Recorder()
    lk = link("image=cam,pose=pose,pose_type=PoseStamped,pose_match=nearest,max_gap=0.02", sink)
    for t in (10.0, 10.1):
        lk.pose("pose", w.pose_stamped(t))
    lk.image("cam", w.image(10.09, w.picture(0)))  # nearest: 10.1 (0.01 s away)
    lk.image("cam", w.image(10.05, w.picture(1)))  # 0.05 s from both: too far
    assert lk.stats.stored == 1 and lk.stats.skipped == {SKIP_GAP: 1}
    assert_pose(sink.frames[0][1], *w.motion(10.1))
    assert sink.frames[0][2] == pytest.approx(10.09)
    # time_source=receive: the stamp is ignored, the receive time given by the caller is used
    sink2 = Recorder()
    lk2 = link("image=cam,pose=pose,time_source=receive", sink2)
    for t in (20.0, 21.0):
        lk2.pose("pose", w.pose_stamped(10.0), recv_t=t)
    lk2.image("cam", w.image(10.0, w.picture(0)), recv_t=20.5)
    assert sink2.frames[0][2] == 20.5


def test_rmw_zenoh_keys_name_the_type() -> None:
    assert rosmsg.type_from_key("0/odom/nav_msgs::msg::dds_::Odometry_/RIHS01_abc") == rosmsg.ODOMETRY
    assert rosmsg.type_from_key("camera/color/image_raw") is None
    sink = Recorder()
    lk = link("image=0/cam/**,pose=0/odom/**", sink)
    lk.pose("0/odom/nav_msgs::msg::dds_::Odometry_/RIHS01_x", w.odom(10.0))
    lk.pose("0/odom/nav_msgs::msg::dds_::Odometry_/RIHS01_x", w.odom(10.2))
    lk.image("0/cam/sensor_msgs::msg::dds_::Image_/RIHS01_y", w.image(10.1, w.picture(0)))
    # bytes of an Image on a key that says CompressedImage: refused, not misread
    lk.image("0/cam/sensor_msgs::msg::dds_::CompressedImage_/RIHS01_z", w.image(10.1, w.picture(0)))
    assert lk.stats.stored == 1 and lk.stats.skipped == {SKIP_TYPE: 1}


def test_the_goal_is_the_answers_plan_in_its_frame() -> None:
    """The link publishes the goal of an answer's plan (`nav.goals`), CDR of the very PoseStamped
    the plan's JSON holds (its frame: the memory's); an answer without a path gives no goal."""
    plan = GoalPlan(PlanResult(ok=True), goal=(1.5, -2.0, math.pi / 2), frame_id="odom")
    goal = goal_of(plan)
    assert goal is not None and goal == pose_stamped(1.5, -2.0, math.pi / 2, frame_id="odom")
    msg = rosmsg.deserialize(goal_bytes(goal, 1700000000.25), rosmsg.POSE_STAMPED)
    assert msg.header.frame_id == "odom"
    assert (msg.header.stamp.sec, msg.header.stamp.nanosec) == (1700000000, 250000000)
    p, q = msg.pose.position, msg.pose.orientation
    assert (p.x, p.y, p.z) == (1.5, -2.0, 0.0)
    assert (q.x, q.y, q.z, q.w) == pytest.approx((0, 0, math.sin(math.pi / 4), math.cos(math.pi / 4)))
    assert read_pose_stamped(rosmsg.to_dict(msg))[:3] == pytest.approx((1.5, -2.0, math.pi / 2))
    assert goal_of(None) is None  # never planned: nothing to drive to
    assert goal_of(GoalPlan(PlanResult(ok=False, reason="unreachable"), frame_id="odom")) is None


@pytest.mark.parametrize(
    ("spec", "message"),
    [
        ("pose=odom", "image=KEY is missing"),
        ("image=cam", "pose=KEY is missing"),
        ("image=cam,pose=odom,colour=red", "unknown key 'colour'"),
        ("image=cam,pose=odom,image=x", "image is given twice"),
        ("image=cam,pose=odom,wait=soon", "wait='soon': Input should be a valid number"),
        ("image=cam,pose=odom,wait=-1", "wait='-1': Input should be greater than or equal to 0"),
        ("image=cam,pose=odom,pose_match=closest", "unknown pose matching 'closest'"),
        ("image=cam,pose=odom,pose_type=Image", "pose_type='Image': not one of"),
        ("image=cam,pose=odom,time_source=gps", "time_source must be 'header' or 'receive'"),
        ("image=cam,pose=odom,parent=map", "unknown key 'parent'"),  # one vocabulary: tf_parent
        ("image=a//b,pose=odom", "not a Zenoh key expression"),
        ("image=cam,pose odom", "'pose odom' is not key=value"),
    ],
)
def test_bad_specs_name_the_problem(spec: str, message: str) -> None:
    with pytest.raises(InputError, match=message):
        LinkConfig.from_spec(spec)


def test_spec_defaults() -> None:
    cfg = LinkConfig.from_spec("image=camera/color/image_raw,pose=odom")
    assert cfg == LinkConfig(image="camera/color/image_raw", pose="odom")
    assert not cfg.tf and cfg.tf_static_key is None and cfg.max_gap is None
    near = LinkConfig.from_spec("image=c,pose=odom,pose_match=nearest", pose_type="Odometry")
    assert near.max_gap == 0.05 and near.pose_type == rosmsg.ODOMETRY


def test_poses_of_another_frame_than_the_memorys_are_not_stored() -> None:
    """The poses' frame (the odometry's header.frame_id, or the TF parent) is checked once
    against the memory's; a memory in `map` takes no `odom` poses."""
    seen: list[str] = []

    def memory_in_map(frame: str) -> str | None:
        seen.append(frame)
        return None if frame == "map" else f"poses in frame {frame!r}, the memory's are in 'map'"

    sink = Recorder()
    lk = RosLink(
        LinkConfig.from_spec("image=cam,pose=odom"), sink, clock=lambda: 5000.0, frame_check=memory_in_map
    )
    for t in POSE_TIMES:
        lk.pose("odom", w.odom(t))
    for i in range(3):
        lk.image("cam", w.image(10.1 + 0.1 * i, w.picture(i)))
    assert sink.calls == 0 and lk.stats.skipped == {"poses in frame 'odom', the memory's are in 'map'": 3}
    assert seen == ["odom"] and lk.poses.frame == "odom"  # asked once
    sink2 = Recorder()
    lk2 = RosLink(LinkConfig.from_spec("image=cam,pose=tf,tf_parent=map"), sink2, frame_check=memory_in_map)
    lk2.pose("tf_static", w.tf_static())
    for t in POSE_TIMES[:3]:
        lk2.pose("tf", w.tf(t))
    lk2.image("cam", w.image(10.1, w.picture(0)))
    assert lk2.stats.stored == 1 and lk2.poses.frame == "map"


@pytest.mark.parametrize("match, gap", [("interpolate", None), ("interpolate", 0.15), ("nearest", 0.05)])
def test_a_pose_topic_lookup_is_the_whole_tracks(match: str, gap: float | None) -> None:
    """The link matches an image on the few pose samples around its stamp; the answer (pose,
    `SKIP_OUTSIDE`, `SKIP_GAP`) is the one a track of every sample kept gives, at stamps on
    samples, between them, across a gap, before the first and after the last, with samples
    arriving late and repeated (the last one kept)."""
    from ravenmem.ingest.poses import PoseTrack
    from ravenmem.ros.link import PoseHistory

    rng = np.random.default_rng(3)
    times = np.round(np.r_[np.arange(10.0, 12.0, 0.1), np.arange(12.5, 13.0, 0.05)], 6)
    hist = PoseHistory(LinkConfig(image="camera", pose="odom", pose_match=match, max_gap=gap))
    kept: dict[float, rosmsg.Sample] = {}
    for t in rng.permutation(np.r_[times, times[::5]]):  # late and repeated samples
        yaw = 0.7 * float(t) + float(rng.normal(0, 0.01))
        s = rosmsg.Sample(
            float(t), (float(t), math.sin(t), 0.0), (0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2))
        )
        hist.add(s, "odom")
        kept[s.t] = s
    order = sorted(kept)
    whole = PoseTrack(order, [kept[t].xyz for t in order], [kept[t].quat for t in order])
    stamps = np.r_[times, times[:-1] + 0.037, 9.9, 9.97, 12.3, 13.0, 13.04, 13.2]
    got = [hist.lookup(float(t)) for t in stamps]
    want = [whole.match(float(t), match, gap) for t in stamps]  # type: ignore[arg-type]
    for t, g, e in zip(stamps, got, want, strict=True):
        if isinstance(e, str):
            assert g == e, t
        else:
            assert (
                isinstance(g, Pose) and np.allclose(g.xyz, e.xyz) and math.isclose(g.yaw, e.yaw, abs_tol=1e-9)
            ), t
    kinds = {g if isinstance(g, str) else "pose" for g in got}
    assert (
        "pose" in kinds
        and SKIP_OUTSIDE in kinds
        and (SKIP_GAP in kinds or match == "interpolate" and gap is None)
    )
