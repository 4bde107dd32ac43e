"""Two explorations of one simulated world whose starts differ: the second robot starts
elsewhere and, like an odometry or a SLAM that starts where the robot is, reports its poses
from its own start (frame `odom`). The offset between the sessions is known exactly."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

import ravenmem
from ravenmem.embed.base import EMBEDDERS
from ravenmem.memory.anchor import Transform
from ravenmem.robot.explore import ExploreConfig
from ravenmem.robot.mission import explore_into
from ravenmem.sim.base import Observation, SceneObject
from ravenmem.sim.synthetic import Box, SyntheticEnv, World
from tests.box_embedder import BoxEmbedder

T0 = 1_700_000_000.0
FIRST_START = (2.0, 1.5, 0.5)
SECOND_START = (13.0, 3.0, math.radians(200.0))  # in the other room, facing back west


def lab_world(start: tuple[float, float, float] = FIRST_START) -> World:
    """Two rooms of different shapes joined by a doorway, an alcove, six coloured boxes: no
    turn or shift of it looks like itself (`synthetic:rooms` does, turned half way round)."""
    walls = [
        (0, 0, 10, 0),
        (10, 0, 10, -3),
        (10, -3, 16, -3),
        (16, -3, 16, 7),
        (16, 7, 6, 7),
        (6, 7, 6, 6),
        (6, 6, 0, 6),
        (0, 6, 0, 0),
        (8, 0, 8, 2.5),
        (8, 4, 8, 6),
    ]
    boxes = [
        Box("RedBox", 3.0, 4.5, color=(210, 40, 40)),
        Box("BlueBox", 12.5, -1.5, color=(40, 60, 210)),
        Box("GreenBox", 14.0, 5.0, half=0.4, height=1.0, color=(40, 170, 60)),
        Box("YellowBox", 5.5, 0.8, half=0.25, color=(210, 200, 40)),
        Box("MagentaBox", 11.0, 4.0, color=(200, 40, 200)),
        Box("CyanBox", 6.8, 1.2, half=0.35, height=1.2, color=(40, 200, 200)),
    ]
    return World(np.asarray(walls, np.float64), boxes, start=start)


class OdomEnv:
    """The rooms world with the robot starting at `start` (world x, y, yaw) and every pose it
    reports taken from there: world -> odom is the inverse of the start pose."""

    def __init__(self, start: tuple[float, float, float], start_time: float) -> None:
        self.env = SyntheticEnv(lab_world(start), name="synthetic:lab", start_time=start_time)
        self.to_odom = Transform(start[0], start[1], 0.0, start[2]).inverse()
        self.name = "synthetic:lab from its second start"
        self.frame_id = "odom"  # REP 105: poses from where the robot started
        self.intrinsics, self.robot = self.env.intrinsics, self.env.robot

    def _odom(self, obs: Observation) -> Observation:
        obs.pose = self.to_odom.apply(obs.pose)
        return obs

    def reset(self) -> Observation:
        return self._odom(self.env.reset())

    def observe(self) -> Observation:
        return self._odom(self.env.observe())

    def step(self, forward: float, turn: float) -> Observation:
        return self._odom(self.env.step(forward, turn))

    def objects(self) -> list[SceneObject]:
        out = []
        for o in self.env.objects():
            x, y = self.to_odom.xy(o.x, o.y)
            out.append(SceneObject(o.id, o.kind, x, y, o.z))
        return out

    def close(self) -> None:
        self.env.close()


def explore(path: Path, env: object, steps: int = 600) -> ravenmem.Memory:
    """Explore `env` into a new memory at `path` (box embedder, keyframes every 0.5 m / 15 deg)."""
    mem = ravenmem.create(path, embedder=BoxEmbedder(), ocr=False, thumb_size=64)
    cfg = ExploreConfig(steps=steps, keyframe_dist=0.5, keyframe_turn=math.radians(15))
    explore_into(env, mem, cfg)  # type: ignore[arg-type]
    return mem


def true_offset() -> Transform:
    """Session 1's map (the world) -> session 2's map (odom from its start)."""
    x, y, yaw = SECOND_START
    return Transform(x, y, 0.0, yaw).inverse()


def yaw_error_deg(a: float, b: float) -> float:
    return abs(math.degrees(float(np.angle(np.exp(1j * (a - b))))))


class TinyImageEmbedder:
    """Place recognition for the tests' world: a picture as its 16 x 12 thumbnail, zero-mean
    and unit length ("tiny images"). The world's walls each have their own shade and its floor
    is a 1 m checkerboard, so two views from about the same pose look alike and views from
    elsewhere do not. Texts match nothing."""

    name = "test-tiny"
    dim = 16 * 12 * 3

    def embed_images(self, images: list[np.ndarray]) -> np.ndarray:
        from PIL import Image

        out = []
        for im in images:
            small = np.asarray(
                Image.fromarray(np.asarray(im, np.uint8)).resize((16, 12), Image.BILINEAR), np.float32
            )
            v = (small - small.mean()).reshape(-1)
            out.append(v / max(float(np.linalg.norm(v)), 1e-6))
        return np.stack(out).astype(np.float32)

    def embed_texts(self, texts: list[str]) -> np.ndarray:
        return np.zeros((len(texts), self.dim), np.float32)


@EMBEDDERS.register("test-tiny")
def _tiny(spec: str = "", **_: object) -> TinyImageEmbedder:
    return TinyImageEmbedder()
