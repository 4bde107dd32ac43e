"""Keyframe selection: stride, target rate, motion novelty, embedding novelty, spec parsing."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from ravenmem.errors import InputError
from ravenmem.ingest.keyframes import (
    DROP_FPS,
    DROP_MOTION,
    DROP_SIMILAR,
    DROP_STRIDE,
    KeyframeConfig,
    Keyframer,
    KeyframeStats,
    NoveltyFilter,
    describe,
    rotation_between,
    select_frames,
)
from ravenmem.types import Frame, Pose

IMG = np.zeros((2, 2, 3), np.uint8)


def frames(ts: Sequence[float], poses: Sequence[Pose | None] | None = None) -> list[Frame]:
    ps = poses if poses is not None else [Pose(0.0, 0.0)] * len(ts)
    return [Frame(IMG, t, p, index=i) for i, (t, p) in enumerate(zip(ts, ps, strict=True))]


def test_only_without_rules_keeps_everything() -> None:
    fs = frames([0.0, 0.0, 1.0])
    assert list(select_frames(fs, KeyframeConfig.only())) == fs
    assert KeyframeConfig.only() == KeyframeConfig.from_spec("all")


def test_stride_keeps_every_nth() -> None:
    st = KeyframeStats()
    kept = list(select_frames(frames([i * 0.1 for i in range(10)]), KeyframeConfig.only(stride=3), st))
    assert [f.index for f in kept] == [0, 3, 6, 9]
    assert st.kept == 4 and st.dropped == {DROP_STRIDE: 6}


def test_fps_uses_slots_robust_to_jitter() -> None:
    rng = np.random.default_rng(0)
    ts = np.arange(0, 10, 1 / 30) + rng.uniform(-0.004, 0.004, 300)
    st = KeyframeStats()
    kept = list(select_frames(frames(list(ts)), KeyframeConfig.only(fps=2.0), st))
    assert len(kept) == 20  # exactly 2 per second over 10 s despite jitter
    assert np.diff([f.t for f in kept]).min() > 0.4
    assert st.dropped == {DROP_FPS: 280}


def test_motion_translation_or_rotation_since_last_kept() -> None:
    poses = [
        Pose(0, 0, yaw=0.0),
        Pose(0.05, 0, yaw=0.0),  # too little
        Pose(0.11, 0, yaw=0.0),  # moved 0.11 from the first kept
        Pose(0.11, 0, yaw=0.1),  # turned 0.1 rad < 0.2
        Pose(0.11, 0, yaw=0.25),  # turned 0.25 rad
        Pose(0.11, 0, yaw=math.pi - 0.05),  # turned a lot
        None,  # no pose: passes, does not reset
        Pose(0.11, 0, yaw=-math.pi + 0.05),  # 0.1 rad across the wrap: too little
    ]
    st = KeyframeStats()
    cfg = KeyframeConfig.only(min_translation=0.1, min_rotation=0.2)
    kept = list(select_frames(frames([float(i) for i in range(8)], poses), cfg, st))
    assert [f.index for f in kept] == [0, 2, 4, 5, 6]
    assert st.dropped == {DROP_MOTION: 3}


def test_motion_uses_full_3d_rotation_when_quaternions_exist() -> None:
    tilt = Pose.from_quaternion(0, 0, 0, math.sin(0.15), 0, 0, math.cos(0.15))  # 0.3 rad roll, yaw 0
    kept = list(
        select_frames(
            frames([0.0, 1.0], [Pose.from_quaternion(0, 0, 0, 0, 0, 0, 1), tilt]),
            KeyframeConfig.only(min_rotation=0.25),
        )
    )
    assert len(kept) == 2


def test_rules_combine_in_order() -> None:
    poses = [Pose(float(i) * 0.01, 0) for i in range(60)]
    cfg = KeyframeConfig.only(stride=2, fps=5.0, min_translation=0.1)
    st = KeyframeStats()
    kept = list(select_frames(frames([i / 30 for i in range(60)], poses), cfg, st))
    xs = [f.pose.x for f in kept if f.pose]
    assert np.diff(xs).min() >= 0.1 - 1e-9
    assert st.kept + sum(st.dropped.values()) == 60
    assert st.dropped[DROP_STRIDE] == 30 and DROP_MOTION in st.dropped


def test_novelty_filter_against_last_kept() -> None:
    nf = NoveltyFilter(0.95)
    a = np.array([1.0, 0.0, 0.0])
    b = np.array([0.97, 0.243, 0.0])  # cos ~0.97 to a
    c = np.array([0.9, 0.436, 0.0])  # cos ~0.9 to a
    assert nf.keep(a) and not nf.keep(b) and nf.keep(c * 7.0)  # scale does not matter
    assert not nf.keep(c) and nf.keep(a)
    assert nf.stats.kept == 3 and nf.stats.dropped == {DROP_SIMILAR: 2}


def test_from_spec_full_spec_and_units() -> None:
    cfg = KeyframeConfig.from_spec(
        "stride=5, fps=2hz,min_translation=10cm,min_rotation=10deg,max_similarity=0.95"
    )
    assert cfg.stride == 5 and cfg.fps == 2.0 and cfg.min_translation == pytest.approx(0.1)
    assert cfg.min_rotation == pytest.approx(math.radians(10)) and cfg.max_similarity == 0.95
    assert KeyframeConfig.from_spec("min_rotation=0.3").min_rotation == 0.3
    assert KeyframeConfig.from_spec("all") == KeyframeConfig.only() == KeyframeConfig.from_spec("none")
    # no spec is the default rules, as for every front end
    assert KeyframeConfig.from_spec(None) == KeyframeConfig() == KeyframeConfig.from_spec("")
    assert cfg.max_interval is None and cfg.novelty_window is None  # rules not named are off


@pytest.mark.parametrize(
    ("spec", "message"),
    [
        ("speed=3", "unknown key 'speed'; choose from stride, fps"),
        ("stride", "'stride' is not key=value"),
        ("stride=2.5", "stride='2.5' must be a whole number"),
        ("stride=0", "stride must be an integer >= 1"),
        ("fps=fast", "fps='fast' is not a number (units: hz)"),
        ("fps=0", "fps must be > 0"),
        ("min_rotation=10furlongs", "min_rotation='10furlongs' is not a number (units: rad/deg)"),
        ("min_translation=-1", "min_translation must be >= 0"),
        ("max_similarity=1.5", "max_similarity is a cosine in [-1, 1]"),
        ("fps=1,fps=2", "fps is given twice"),
    ],
)
def test_from_spec_errors(spec: str, message: str) -> None:
    with pytest.raises(InputError) as e:
        KeyframeConfig.from_spec(spec)
    assert message in str(e.value)


def test_keyframer_online_gives_the_reason_for_each_dropped_frame() -> None:
    from ravenmem.ingest.keyframes import Keyframer

    kf = Keyframer(KeyframeConfig.only(min_translation=0.5, max_similarity=0.95))
    poses = [Pose(0.0, 0.0), Pose(0.1, 0.0), Pose(1.0, 0.0), Pose(2.0, 0.0)]
    embs = [np.array([1.0, 0.0]), None, np.array([0.999, 0.04]), np.array([0.0, 1.0])]
    out = []
    for f, e in zip(frames([0.0, 1.0, 2.0, 3.0], poses), embs, strict=True):
        reason = kf.pre(f)
        if reason is None:
            assert e is not None
            reason = kf.post(e)
        out.append(reason)
    assert out == [None, DROP_MOTION, DROP_SIMILAR, None]
    assert kf.stats.kept == 2 and kf.stats.dropped == {DROP_MOTION: 1, DROP_SIMILAR: 1}


def test_default_rules_are_motion_and_novelty() -> None:
    cfg = KeyframeConfig()
    assert cfg.min_translation == 0.5 and cfg.min_rotation == pytest.approx(math.radians(15))
    assert cfg.max_interval == 5.0 and cfg.max_similarity == 0.97 and cfg.novelty_window == 30.0
    assert cfg.stride == 1 and cfg.fps is None
    assert KeyframeConfig.from_spec("default") == cfg
    assert KeyframeConfig(stride=3) == replace(cfg, stride=3)  # the constructor starts from the defaults
    text = describe(cfg)
    assert "moved 0.5 m or turned 15 deg or 5 s passed" in text and "cosine <= 0.97" in text
    assert describe(KeyframeConfig.only()) == "every frame"


def test_parse_default_with_changes_and_units() -> None:
    cfg = KeyframeConfig.from_spec("default, max_similarity=0.9, novelty_window=2min, max_interval=500ms")
    assert cfg == replace(KeyframeConfig(), max_similarity=0.9, novelty_window=120.0, max_interval=0.5)
    assert KeyframeConfig.from_spec("fps=2").min_rotation is None  # without 'default' only the named rules
    with pytest.raises(InputError, match="max_interval must be > 0"):
        KeyframeConfig.from_spec("max_interval=0")
    with pytest.raises(InputError, match="'default' is not key=value"):
        KeyframeConfig.from_spec("fps=2,default")  # 'default' only leads the spec


def test_still_camera_is_looked_at_every_max_interval() -> None:
    kf = Keyframer(KeyframeConfig.only(min_rotation=0.3, max_interval=5.0))
    out = [kf.pre(f) for f in frames([i * 0.5 for i in range(25)])]  # 12 s, never moves
    assert [i for i, r in enumerate(out) if r is None] == [0, 10, 20]  # t = 0, 5, 10 s
    assert kf.stats.dropped == {DROP_MOTION: 22}


def test_still_scene_is_stored_once_per_novelty_window() -> None:
    """Default rules on a parked robot: a candidate every 5 s, all alike; one kept per 30 s, and a
    change in the scene is kept at the next candidate."""
    kf = Keyframer(KeyframeConfig())
    wall, person = np.array([1.0, 0.0]), np.array([0.6, 0.8])
    kept = []
    for f in frames([float(t) for t in range(0, 121)]):  # 2 minutes at 1 frame/s
        if kf.pre(f) is None and kf.post(person if 50 <= f.t < 60 else wall) is None:
            kept.append(f.t)
    # the wall at 0 and again at 35 (the first candidate > 30 s later); the person at 50; the
    # wall at 60 (it changed back), and at 95 (window)
    assert kept == [0.0, 35.0, 50.0, 60.0, 95.0]


def test_batched_pre_then_post_uses_each_frames_own_time() -> None:
    """The pipeline runs `pre` over a batch, then `post` over the same frames in order."""
    cfg = KeyframeConfig.only(max_similarity=0.9, novelty_window=10.0)
    same = np.array([1.0, 0.0])
    one_by_one, batched = Keyframer(cfg), Keyframer(cfg)
    fs = frames([0.0, 4.0, 8.0, 12.0, 16.0, 20.0, 24.0])
    a = [one_by_one.pre(f) or one_by_one.post(same) for f in fs]
    assert all(batched.pre(f) is None for f in fs)
    b = [batched.post(same) for _ in fs]
    assert a == b == [None, DROP_SIMILAR, DROP_SIMILAR, None, DROP_SIMILAR, DROP_SIMILAR, None]


def test_novelty_compares_with_the_last_keyframe_only() -> None:
    """A view the camera comes back to is kept again: revisits carry the "last seen" times."""
    nf = NoveltyFilter(0.95)
    a, b = np.array([1.0, 0.0]), np.array([0.0, 1.0])
    assert [nf.keep(v) for v in (a, b, a, a)] == [True, True, True, False]


def test_default_rules_on_real_tum_keep_distinct_views(tum_path: Path) -> None:
    """The cheap rules on the real hand-held sequence: 723 frames, ~1560 deg of turning in 24 s.
    (The novelty rule on top, with the real embedder, is measured by benchmarks/bench_keyframes.py.)"""
    from ravenmem.ingest.sources import open_source

    kf = Keyframer(replace(KeyframeConfig(), max_similarity=None))
    kept = [f for f in open_source(tum_path) if kf.pre(f) is None]
    assert 75 <= len(kept) <= 95  # 80 measured: a candidate every ~0.3 s of fast turning
    turns = [rotation_between(a.pose, b.pose) for a, b in zip(kept, kept[1:])]  # type: ignore[arg-type]
    assert min(turns) >= math.radians(15) - 1e-9
