"""A world that changes: verdicts against ground truth, and what the latest mode costs.

    PYTHONPATH=src python benchmarks/bench_changes.py [--sizes 10000,100000] [--skip-scenarios]

1. Scenarios (the synthetic two-room world, a real exploration on day 1 and another on day 2,
   one memory; the pixel-share embedder of tests/robot/box_embedder.py): a static world, the
   red box moved to five places (and the green box taken away), the blue box taken away and the
   green box moved. For each box: the thing's status from `Memory.last_seen` against the truth
   (moved / gone / unchanged), and whether the place it says the box is at now shows it.
2. Scale: a robot patrols a 40 x 40 m square corridor (a keyframe every 0.5 m, 1 s apart,
   embeddings of dim 384 from the look of each stretch plus noise); a mug sits at one stretch,
   is moved to another halfway through, a kettle is taken away at 80 %, a plant never moves.
   Printed side by side for each size: the plain text tool (`search_text`, k=5) and the latest
   mode (`last_seen`), p50 and p90 over repeated calls, and whether the verdicts are right.
"""

from __future__ import annotations

import argparse
import math
import shutil
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))
sys.path.insert(0, str(ROOT))

import ravenmem  # noqa: E402
from ravenmem.robot.explore import ExploreConfig  # noqa: E402
from ravenmem.robot.mission import explore_into  # noqa: E402
from ravenmem.sim.synthetic import SyntheticEnv  # noqa: E402
from ravenmem.types import Frame, Pose  # noqa: E402
from tests.box_embedder import BoxEmbedder  # noqa: E402

T0 = 1_700_000_000.0
DAY = 86_400.0
BOXES = {"red box": 0, "blue box": 1, "green box": 2}
HOME = {0: (3.0, 4.5), 1: (12.5, 1.5), 2: (14.0, 4.8)}


# ------------------------------------------------------------------------------- scenarios
def scenario(
    folder: Path, change: Callable[[SyntheticEnv], dict[int, tuple[float, float] | None]]
) -> list[str]:
    """Explore, change the world, explore again; one row per box: truth, status, now-place ok."""
    env = SyntheticEnv(start_time=T0)
    mem = ravenmem.create(folder, embedder=BoxEmbedder(), ocr=False, thumb_size=0)
    cfg = ExploreConfig(steps=700, resolution=0.2, keyframe_dist=1.0)
    explore_into(env, mem, cfg)
    where = change(env)  # object id -> new place, or None when taken away
    env.start_time = T0 + DAY
    explore_into(env, mem, cfg)
    rows = []
    for name, oid in BOXES.items():
        w = mem.last_seen(name)
        truth = "unchanged" if oid not in where else ("gone" if where[oid] is None else "moved")
        now = w.now  # the place it is at now must show it: render the day-2 world from that camera
        shows = now is not None and oid in env.render(now.last.pose.x, now.last.pose.y, now.last.pose.yaw)[2]
        if truth == "gone":
            checks = ["status gone: " + ("yes" if w.status == "gone" else "NO")]
        else:
            checks = ["now-place shows it: " + ("yes" if shows else "NO")]
        if truth == "moved":
            checks.append(
                "old place moved: " + ("yes" if any(p.verdict == "moved" for p in w.places) else "NO")
            )
        if truth == "unchanged":
            false = [p.verdict for p in w.places if p.verdict in ("moved", "gone")]
            checks.append("no false moved/gone: " + ("yes" if not false else f"NO ({len(false)})"))
        places = ",".join(p.verdict for p in w.places)
        rows.append(
            f"  {name:10s} truth {truth:9s} status {str(w.status):13s} {'; '.join(checks)}  [{places}]"
        )
    mem.close()
    return rows


def scenarios() -> None:
    def moved_red(x: float, y: float) -> Callable[[SyntheticEnv], dict[int, tuple[float, float] | None]]:
        def change(env: SyntheticEnv) -> dict[int, tuple[float, float] | None]:
            env.move_object(0, x, y)
            env.remove_object(2)
            return {0: (x, y), 2: None}

        return change

    def blue_gone(env: SyntheticEnv) -> dict[int, tuple[float, float] | None]:
        env.remove_object(1)
        env.move_object(2, 3.0, 1.2)
        return {1: None, 2: (3.0, 1.2)}

    cases: dict[str, Callable[[SyntheticEnv], dict[int, tuple[float, float] | None]]] = {
        "static world": lambda env: {}
    }
    for xy in [(14.5, 1.0), (10.0, 0.8), (5.5, 1.0), (12.0, 5.2), (6.5, 4.8)]:
        cases[f"red box -> {xy}, green box taken away"] = moved_red(*xy)
    cases["blue box taken away, green box -> (3.0, 1.2)"] = blue_gone
    with tempfile.TemporaryDirectory() as tmp:
        for i, (label, change) in enumerate(cases.items()):
            t = time.perf_counter()
            rows = scenario(Path(tmp) / f"s{i}.mem", change)
            print(f"{label} ({time.perf_counter() - t:.1f} s)")
            print("\n".join(rows))


# ------------------------------------------------------------------------------- scale
class Labels:
    """Texts name one of the patrol's things; each has its own direction in the embedding space."""

    name = "bench-labels"

    def __init__(self, dim: int, things: dict[str, np.ndarray]) -> None:
        self.dim, self.things = dim, things

    def embed_texts(self, texts: Sequence[str]) -> np.ndarray:
        return np.stack([self.things[t] for t in texts])

    def embed_images(self, images: Sequence[np.ndarray]) -> np.ndarray:
        raise NotImplementedError("the benchmark stores precomputed embeddings")


def patrol(
    n: int, dim: int, seed: int = 0
) -> tuple[list[Pose], np.ndarray, dict[str, np.ndarray], dict[str, list[tuple[int, float, float]]]]:
    """Poses along a square loop and their embeddings; where each thing is, lap by lap."""
    rng = np.random.default_rng(seed)
    side, step = 40.0, 0.5
    per_lap = int(4 * side / step)
    look = rng.normal(size=(per_lap // 8 + 2, dim)).astype(np.float32)  # the look of each 4 m stretch
    things: dict[str, np.ndarray] = {
        k: (v / np.linalg.norm(v)).astype(np.float32)
        for k, v in zip(("mug", "kettle", "plant"), rng.normal(size=(3, dim)))
    }
    laps = n / per_lap
    # thing -> [(keyframe along the lap where it comes into view, from lap, to lap)]
    where: dict[str, list[tuple[int, float, float]]] = {
        "mug": [(10, 0, laps / 2), (50, laps / 2, laps)],
        "kettle": [(30, 0, 0.8 * laps)],
        "plant": [(70, 0, laps)],
    }
    poses, emb = [], np.empty((n, dim), np.float32)
    for i in range(n):
        lap, s = divmod(i, per_lap)
        d = s * step
        edge, along = divmod(d, side)
        x, y, yaw = [
            (along, 0.0, 0.0),
            (side, along, math.pi / 2),
            (side - along, side, math.pi),
            (0.0, side - along, -math.pi / 2),
        ][int(edge)]
        poses.append(Pose(x, y, 1.0, yaw))
        v = look[s // 8] + rng.normal(0, 0.3, dim).astype(np.float32)
        for thing, spans in where.items():
            for at, a, b in spans:
                if a <= lap < b and 0 <= s - at < 6:  # in view for 6 keyframes (3 m) per lap
                    v = v + math.sqrt(dim) * things[thing]  # as strong as the look of the stretch
        emb[i] = v / np.linalg.norm(v)
    return poses, emb, things, where


def build_patrol(path: Path, n: int, dim: int) -> ravenmem.Memory:
    """A patrol memory of `n` keyframes at `path` (embeddings stored as given: no model runs)."""
    poses, emb, things, _ = patrol(n, dim)
    mem = ravenmem.create(path, embedder=Labels(dim, things), ocr=False, thumb_size=0)
    img = np.zeros((2, 2, 3), np.uint8)
    for a in range(0, n, 5000):
        frames = [Frame(img, T0 + i, poses[i], "patrol", i) for i in range(a, min(n, a + 5000))]
        mem.add_frames(frames, embeddings=emb[a : a + len(frames)])
    return mem


def verdicts(mem: ravenmem.Memory) -> list[str]:
    """Whether the latest mode gets the patrol's changes right (mug moved, kettle gone, plant there)."""
    checks = []
    mug, kettle, plant = mem.last_seen("mug"), mem.last_seen("kettle"), mem.last_seen("plant")
    at_mug = mug.now is not None and abs(mug.now.last.frame_index % 320 - 50) < 8
    checks.append(f"mug now at its new stretch: {'yes' if at_mug else 'NO'}, status {mug.status}")
    checks.append(f"old place {'moved' if any(p.verdict == 'moved' for p in mug.places) else 'NOT moved'}")
    checks.append(f"kettle {kettle.status}")
    checks.append(f"plant {plant.status}")
    return checks


def timings(mem: ravenmem.Memory, reps: int) -> tuple[list[float], list[float]]:
    """Seconds per call of the text tool (k=5) and of the latest mode, alternating."""
    st, ls = [], []
    for _ in range(reps):
        t = time.perf_counter()
        mem.search_text("mug", k=5)
        st.append(time.perf_counter() - t)
        t = time.perf_counter()
        mem.last_seen("mug")
        ls.append(time.perf_counter() - t)
    return st, ls


def scale(sizes: list[int], dim: int, reps: int) -> None:
    print(f"\nscale: patrol loop, dim {dim}; p50 / p90 ms over {reps} calls (2 busy cores)")
    print(
        f"{'memories':>9} {'build s':>8} | {'search_text p50':>15} {'p90':>6} | {'last_seen p50':>13} {'p90':>6} | verdicts"
    )
    for n in sizes:
        tmp = Path(tempfile.mkdtemp(prefix="bench-changes-"))
        try:
            t = time.perf_counter()
            mem = build_patrol(tmp / "p.mem", n, dim)
            build = time.perf_counter() - t
            st, ls = timings(mem, reps)
            checks = verdicts(mem)
            mem.close()
        finally:
            shutil.rmtree(tmp, ignore_errors=True)
        p = lambda xs, q: 1000 * float(np.percentile(xs, q))  # noqa: E731
        print(
            f"{n:>9} {build:>8.1f} | {p(st, 50):>15.1f} {p(st, 90):>6.1f} | {p(ls, 50):>13.1f} {p(ls, 90):>6.1f} | "
            + "; ".join(checks)
        )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sizes", default="10000,100000")
    ap.add_argument("--dim", type=int, default=384)
    ap.add_argument("--reps", type=int, default=20)
    ap.add_argument("--skip-scenarios", action="store_true")
    args = ap.parse_args()
    if not args.skip_scenarios:
        scenarios()
    scale([int(s) for s in args.sizes.split(",") if s], args.dim, args.reps)


if __name__ == "__main__":
    main()
