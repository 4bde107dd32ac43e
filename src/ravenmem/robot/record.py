"""Record a simulated robot's drive as a TUM RGB-D folder: a real-layout RGB-D recording with
exact ground truth, to test mapping from recordings where no real depth data is at hand.

Layout (the benchmark's own): `rgb/` and `depth/` PNGs, `rgb.txt` and `depth.txt`
(`timestamp filename`), `groundtruth.txt` (`timestamp tx ty tz qx qy qz qw`: the colour
camera's OPTICAL frame, x right, y down, z forward, as TUM writes it) and `camera.txt`
(`fx fy cx cy width height`). Depth is 16-bit, 5000 units per metre; readings beyond 13.1 m
(the format's limit) or missing are 0, as a real sensor reports them.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from PIL import Image
from scipy.spatial.transform import Rotation

from ..errors import InputError
from ..fsio import atomic_write
from ..sim.base import Environment, Observation
from .explore import ExploreConfig, Explorer

DEPTH_SCALE = 5000.0
# The optical frame (x right, y down, z forward) in a z-up body frame (x forward, y left).
OPTICAL_IN_BODY = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


def optical_quaternion(yaw: float) -> tuple[float, float, float, float]:
    """(qx, qy, qz, qw) of a level camera's optical frame heading `yaw` in a z-up world."""
    c, s = math.cos(yaw), math.sin(yaw)
    rz = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    q = Rotation.from_matrix(rz @ OPTICAL_IN_BODY).as_quat()
    return (float(q[0]), float(q[1]), float(q[2]), float(q[3]))


@dataclass
class Recorder:
    """Wraps an environment and writes every observation it returns into a TUM folder."""

    env: Environment
    folder: Path
    frames: int = 0
    _rgb: list[str] = field(default_factory=list)
    _depth: list[str] = field(default_factory=list)
    _gt: list[str] = field(default_factory=list)
    _last_t: float = -math.inf

    def __post_init__(self) -> None:
        (self.folder / "rgb").mkdir(parents=True, exist_ok=True)
        (self.folder / "depth").mkdir(parents=True, exist_ok=True)

    def __getattr__(self, name: str) -> Any:  # name, intrinsics, robot, objects(), ...
        return getattr(self.env, name)

    def _write(self, obs: Observation) -> Observation:
        if obs.t <= self._last_t:  # one frame per instant (TUM timestamps are unique)
            return obs
        self._last_t = obs.t
        stamp = f"{obs.t:.6f}"
        Image.fromarray(obs.rgb).save(self.folder / "rgb" / f"{stamp}.png", compress_level=1)
        d = np.asarray(obs.depth, np.float64) * DEPTH_SCALE
        d = np.where((d > 0) & (d < 65535), np.round(d), 0).astype(np.uint16)
        Image.fromarray(d).save(self.folder / "depth" / f"{stamp}.png", compress_level=1)
        p = obs.pose
        qx, qy, qz, qw = optical_quaternion(p.yaw)
        self._rgb.append(f"{stamp} rgb/{stamp}.png")
        self._depth.append(f"{stamp} depth/{stamp}.png")
        self._gt.append(f"{stamp} {p.x:.6f} {p.y:.6f} {p.z:.6f} {qx:.9f} {qy:.9f} {qz:.9f} {qw:.9f}")
        self.frames += 1
        return obs

    def reset(self) -> Observation:
        return self._write(self.env.reset())

    def observe(self) -> Observation:
        return self._write(self.env.observe())

    def step(self, forward: float, turn: float) -> Observation:
        return self._write(self.env.step(forward, turn))

    def finish(self) -> None:
        """Write the index files (atomically)."""
        head = "# written by ravenmem.robot.record\n# timestamp filename\n"
        atomic_write(self.folder / "rgb.txt", head + "\n".join(self._rgb) + "\n")
        atomic_write(self.folder / "depth.txt", head + "\n".join(self._depth) + "\n")
        atomic_write(
            self.folder / "groundtruth.txt",
            "# timestamp tx ty tz qx qy qz qw (optical frame)\n" + "\n".join(self._gt) + "\n",
        )
        i = self.env.intrinsics
        atomic_write(self.folder / "camera.txt", f"{i.fx} {i.fy} {i.cx} {i.cy} {i.width} {i.height}\n")


def record_tum(
    env: Environment,
    folder: str | Path,
    steps: int = 300,
    progress: Callable[[str], None] | None = None,
) -> dict[str, Any]:
    """Explore `env` for `steps` control steps, writing every frame as a TUM RGB-D folder.
    Returns (and saves as `truth.json`) the scene's objects, the trajectory and the camera."""
    folder = Path(folder)
    if folder.exists() and any(folder.iterdir()):
        raise InputError(f"{folder} is not empty")
    rec = Recorder(env, folder)
    ex = Explorer(rec, None, ExploreConfig(steps=steps), progress=progress)  # type: ignore[arg-type]
    report = ex.run(reset=True)
    rec.finish()
    i = env.intrinsics
    truth = {
        "env": env.name,
        "frames": rec.frames,
        "camera": {"fx": i.fx, "fy": i.fy, "cx": i.cx, "cy": i.cy, "width": i.width, "height": i.height},
        "robot": env.robot.__dict__,
        "trajectory": [list(p) for p in report.trajectory],
        "objects": [o.__dict__ for o in env.objects()],
    }
    atomic_write(folder / "truth.json", json.dumps(truth))
    return truth
