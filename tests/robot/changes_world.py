"""The world that changes: the two-room world explored on day 1, the red box moved to the other
room and the green box taken away, explored again on day 2 into the same memory (real explorer,
real memory; the pixel-share test embedder). Built once per session by the `world` fixture."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import ravenmem
from ravenmem.robot.explore import ExploreConfig, ExploreReport
from ravenmem.robot.mission import explore_into
from ravenmem.sim.synthetic import SyntheticEnv
from tests.box_embedder import BoxEmbedder

T0 = 1_700_000_000.0
DAY = 86_400.0
RED, BLUE, GREEN = 0, 1, 2  # object ids of rooms_world()
A = (3.0, 4.5)  # where the red box starts (room 1)
B = (14.5, 1.0)  # where it is moved (room 2, out of sight from room 1 through the doorway)
CFG = ExploreConfig(steps=700, resolution=0.2, keyframe_dist=1.0)


@dataclass
class World:
    mem: ravenmem.Memory
    path: Path
    runs: tuple[ExploreReport, ExploreReport]
    day1: SyntheticEnv  # the world as it was on day 1 (for "what would this view have shown")
    day2_start: float

    def showed(self, mid: int, obj: int) -> bool:
        """Ground truth: whether keyframe `mid` showed object `obj`."""
        for rep in self.runs:
            if mid in rep.keyframes:
                return obj in rep.keyframes[mid]
        raise KeyError(mid)


def build_world(path: Path) -> World:
    """Explore on day 1, move the red box to B and take the green box away, explore on day 2."""
    env = SyntheticEnv(start_time=T0)
    mem = ravenmem.create(path, embedder=BoxEmbedder(), ocr=False, thumb_size=64)
    _, run1 = explore_into(env, mem, CFG)
    env.move_object(RED, *B)
    env.remove_object(GREEN)
    env.start_time = T0 + DAY
    _, run2 = explore_into(env, mem, CFG)
    assert min(run2.keyframes) > max(run1.keyframes)  # appended, ids after the first run's
    return World(mem, path, (run1, run2), SyntheticEnv(start_time=T0), T0 + DAY)
