"""Video source: a small mp4 written here with PyAV (known pts) + a CSV pose track."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import av
import numpy as np
import pytest

from ravenmem.errors import InputError
from ravenmem.ingest.poses import SKIP_OUTSIDE
from ravenmem.ingest.video import SKIP_CORRUPT, SKIP_ENDED_EARLY, SKIP_FPS, VideoSource

W, H, N, RATE = 64, 48, 30, 10
COLOURS = [(200, 30, 30), (30, 200, 30), (30, 30, 200)]


def write_video(path: Path, bad_packets: frozenset[int] = frozenset(), creation: str | None = None) -> None:
    """N frames at RATE fps (frame i at i/RATE s), colour cycling red/green/blue."""
    rng = np.random.default_rng(0)
    with av.open(str(path), "w") as c:
        if creation:
            c.metadata["creation_time"] = creation
        s = c.add_stream("mpeg4", rate=RATE)
        s.width, s.height, s.pix_fmt = W, H, "yuv420p"
        k = 0

        def mux(packets: list[av.Packet]) -> None:
            nonlocal k
            for p in packets:
                if k in bad_packets:  # replace the payload with garbage, keep the timing
                    q = av.Packet(bytes(rng.integers(0, 256, p.size, dtype=np.uint8)))
                    q.pts, q.dts, q.time_base, q.stream = p.pts, p.dts, p.time_base, s
                    p = q
                c.mux(p)
                k += 1

        for i in range(N):
            img = np.zeros((H, W, 3), np.uint8)
            img[:] = COLOURS[i % 3]
            f = av.VideoFrame.from_ndarray(img, format="rgb24")
            f.pts = i
            mux(s.encode(f))
        mux(s.encode())


@pytest.fixture(scope="module")
def video(tmp_path_factory: pytest.TempPathFactory) -> Path:
    p = tmp_path_factory.mktemp("video") / "walk.mp4"
    write_video(p, creation="2024-05-01T10:00:00.000000Z")
    return p


@pytest.fixture()
def poses(tmp_path: Path) -> Path:
    # covers 0.5 s .. 2.0 s: frames 5..20 of 0..29; x goes 0 -> 3 m, yaw 0 -> 1.5 rad
    p = tmp_path / "poses.csv"
    p.write_text("t,x,y,z,yaw\n0.5,0,0,0,0\n2.0,3,1.5,0,1.5\n")
    return p


def test_frames_times_poses_and_skips(video: Path, poses: Path) -> None:
    src = VideoSource(video, poses=poses)
    frames = list(src)
    assert [f.index for f in frames] == list(range(5, 21))
    assert [f.t for f in frames] == pytest.approx([i / RATE for i in range(5, 21)])
    f = frames[5]  # frame 10 at t = 1.0 s: a third of the way
    assert f.pose is not None
    assert (f.pose.x, f.pose.y, f.pose.yaw) == pytest.approx((1.0, 0.5, 0.5))
    assert f.image.shape == (H, W, 3) and f.image.dtype == np.uint8 and f.image.flags.writeable
    for fr in frames:  # the decoded colour is the one written (lossy codec: dominant channel)
        assert int(np.argmax(fr.image[H // 2, W // 2])) == fr.index % 3
    st = src.stats
    assert st.frames_seen == N and st.frames_yielded == 16
    assert st.skipped == {SKIP_OUTSIDE: 14}
    assert st.raw_bytes == N * W * H * 3
    assert f.source == str(video) and src.name == "video:walk.mp4"


def test_iterating_twice_resets_stats(video: Path, poses: Path) -> None:
    src = VideoSource(video, poses=poses)
    assert len(list(src)) == len(list(src)) == 16
    assert src.stats.frames_seen == N


def test_start_time_offsets_to_epoch(video: Path, tmp_path: Path) -> None:
    p = tmp_path / "epoch.csv"
    p.write_text("1700000000.5,0,0,0\n1700000002.0,3,0,0\n")
    frames = list(VideoSource(video, poses=p, start_time=1_700_000_000.0))
    assert len(frames) == 16 and frames[0].t == pytest.approx(1_700_000_000.5)
    iso = list(VideoSource(video, poses=p, start_time="2023-11-14T22:13:20Z"))
    assert [f.t for f in iso] == [f.t for f in frames]


def test_creation_time_tag(video: Path, tmp_path: Path) -> None:
    t0 = 1714557600.0  # 2024-05-01T10:00:00Z
    p = tmp_path / "p.csv"
    p.write_text(f"{t0},0,0,0\n{t0 + 10},1,0,0\n")
    frames = list(VideoSource(video, poses=p, start_time="creation_time"))
    assert len(frames) == N and frames[0].t == pytest.approx(t0)


def test_fps_prefilter_skips_conversion(video: Path, poses: Path) -> None:
    src = VideoSource(video, poses=poses, fps=5.0)
    frames = list(src)
    assert [f.index for f in frames] == list(range(5, 21, 2))
    assert src.stats.skipped == {SKIP_OUTSIDE: 14, SKIP_FPS: 8}
    assert src.stats.raw_bytes == N * W * H * 3


def test_nearest_matching_option(video: Path, poses: Path) -> None:
    frames = list(VideoSource(video, poses=poses, pose_match="nearest", max_gap=0.05))
    assert [f.index for f in frames] == [5, 20]


def test_pose_track_required_unless_allowed(video: Path) -> None:
    with pytest.raises(InputError, match="needs a pose track"):
        VideoSource(video)
    frames = list(VideoSource(video, allow_no_pose=True))
    assert len(frames) == N and all(f.pose is None for f in frames)


def test_corrupt_packet_is_skipped_and_counted(tmp_path: Path, poses: Path) -> None:
    p = tmp_path / "damaged.mkv"
    write_video(p, bad_packets=frozenset({12}))
    src = VideoSource(p, poses=poses)
    frames = list(src)
    assert src.stats.skipped.get(SKIP_CORRUPT, 0) >= 1
    assert len(frames) + sum(src.stats.skipped.values()) == src.stats.frames_seen
    assert len(frames) >= 10


def test_unreadable_files_are_clear_errors(tmp_path: Path, poses: Path) -> None:
    junk = tmp_path / "junk.mp4"
    junk.write_bytes(np.random.default_rng(1).integers(0, 256, 4000, dtype=np.uint8).tobytes())
    with pytest.raises(InputError, match=r"junk\.mp4: not a readable video"):
        VideoSource(junk, poses=poses)
    with pytest.raises(InputError, match="video file not found"):
        VideoSource(tmp_path / "missing.mp4", poses=poses)
    with pytest.raises(InputError, match="pose file not found"):
        VideoSource(junk, poses=tmp_path / "nope.csv")
    with pytest.raises(InputError, match="no creation_time tag"):
        write_video(tmp_path / "plain.mp4")
        VideoSource(tmp_path / "plain.mp4", poses=poses, start_time="creation_time")
    with pytest.raises(InputError, match="start time 'yesterday'"):
        VideoSource(tmp_path / "plain.mp4", poses=poses, start_time="yesterday")


def write_long_video(path: Path, n: int = 120, faststart: bool = True) -> None:
    """n frames of noise at RATE fps (so that every frame costs bytes), index at the front."""
    rng = np.random.default_rng(3)
    with av.open(str(path), "w", options={"movflags": "faststart"} if faststart else {}) as c:
        s = c.add_stream("mpeg4", rate=RATE)
        s.width, s.height, s.pix_fmt = W, H, "yuv420p"
        for i in range(n):
            f = av.VideoFrame.from_ndarray(rng.integers(0, 256, (H, W, 3), dtype=np.uint8), format="rgb24")
            f.pts = i
            for p in s.encode(f):
                c.mux(p)
        for p in s.encode():
            c.mux(p)


def truncate(path: Path, fraction: float) -> Path:
    data = path.read_bytes()
    out = path.with_name("cut_" + path.name)
    out.write_bytes(data[: int(len(data) * fraction)])
    return out


def test_truncated_mkv_is_noticed_by_its_duration(tmp_path: Path) -> None:
    """No frame count in a Matroska file: the container's duration says how long it should be."""
    whole = tmp_path / "long.mkv"
    write_long_video(whole)
    p = tmp_path / "p.csv"
    p.write_text("t,x,y\n0,0,0\n20,1,0\n")
    full = VideoSource(whole, poses=p)
    assert len(list(full)) == 120 and full.stats.warnings == [] and full.frame_count == 120
    cut = VideoSource(truncate(whole, 0.45), poses=p)
    n = len(list(cut))
    assert 20 < n < 100 and cut.frame_count == 120
    missing = cut.stats.skipped[SKIP_ENDED_EARLY]
    assert abs(n + missing - 120) <= 2  # an estimate from the duration
    assert len(cut.stats.warnings) == 1 and f"{n} of about 120 frames" in cut.stats.warnings[0]


def test_truncated_faststart_mp4_warns_and_still_stores(tmp_path: Path) -> None:
    """The issue's case: a faststart mp4 cut in half ingests what it has, says it ended early
    (stderr and JSON) and exits 0; the whole file has no warning."""
    whole = tmp_path / "long.mp4"
    write_long_video(whole)
    cut = truncate(whole, 0.45)
    (tmp_path / "p.csv").write_text("t,x,y\n0,0,0\n20,1,0\n")
    env = dict(os.environ, PYTHONPATH=str(Path(__file__).resolve().parents[2] / "src"))

    def ingest(video: Path, mem: str) -> subprocess.CompletedProcess[str]:
        opts = (
            f"--poses {tmp_path / 'p.csv'} --no-ocr --keyframes stride=20 --embedder offline:tiles=1:res=128"
        )
        cmd = [sys.executable, "-m", "ravenmem.cli.main", "ingest", str(video), "--json", *opts.split()]
        cmd += ["--memory", str(tmp_path / mem)]
        return subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=600)

    r = ingest(cut, "cut.mem")
    assert r.returncode == 0, r.stderr
    rep = json.loads(r.stdout)
    decoded = rep["frames_seen"]
    assert 20 < decoded < 100 and rep["kept"] == len(range(0, decoded, 20))
    assert rep["skipped"][SKIP_ENDED_EARLY] == 120 - decoded
    assert len(rep["warnings"]) == 1 and f"{decoded} of 120 frames decoded" in rep["warnings"][0]
    warning = [line for line in r.stderr.splitlines() if line.startswith("warning:")]
    assert len(warning) == 1 and "ended early" in warning[0] and "cut_long.mp4" in warning[0]

    full = VideoSource(whole, poses=tmp_path / "p.csv")
    assert len(list(full)) == 120 and full.stats.warnings == [] and SKIP_ENDED_EARLY not in full.stats.skipped
