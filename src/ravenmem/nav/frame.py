"""Where a map lies in the world: the floor plane and the map's two axes on it.

A map is 2-D; the recording it came from is 3-D, in whatever frame its poses use. The map
frame says which way is up (`up`, a unit vector in world coordinates), where the floor is
(`floor`: world points p on the floor have p . up == floor) and which world directions the
map's x and y axes are (`axes`). Map coordinates of a world point p are (axes[0] . p,
axes[1] . p); its height above the floor is p . up - floor.

When up lies within `SNAP_DEG` of a world axis, the map's axes are the other two world axes
(right-handed with up), so for the usual z-up worlds (ROS, simulators) map x, y are simply
world x, y and positions from the memory read directly on the map. Heights always use the
fitted plane, so a slightly tilted floor does not turn into obstacles far from the camera.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..errors import InputError

SNAP_DEG = 10.0
Vec3 = tuple[float, float, float]

# For up = +/- each world axis: the map's (x, y) world axes, right-handed (x cross y == up).
_AXES_FOR_UP: dict[tuple[int, int], tuple[Vec3, Vec3]] = {
    (2, 1): ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0)),
    (2, -1): ((0.0, 1.0, 0.0), (1.0, 0.0, 0.0)),
    (1, 1): ((0.0, 0.0, 1.0), (1.0, 0.0, 0.0)),
    (1, -1): ((1.0, 0.0, 0.0), (0.0, 0.0, 1.0)),
    (0, 1): ((0.0, 1.0, 0.0), (0.0, 0.0, 1.0)),
    (0, -1): ((0.0, 0.0, 1.0), (0.0, 1.0, 0.0)),
}


def _unit(v: np.ndarray) -> np.ndarray:
    n = float(np.linalg.norm(v))
    if not math.isfinite(n) or n < 1e-9:
        raise InputError(f"not a direction: {v}")
    return np.asarray(v, np.float64) / n


@dataclass(frozen=True)
class MapFrame:
    """The floor plane and map axes in world coordinates (see the module docstring)."""

    up: Vec3 = (0.0, 0.0, 1.0)
    floor: float = 0.0
    axes: tuple[Vec3, Vec3] = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0))
    method: str = "z up"

    @classmethod
    def from_up(cls, up: np.ndarray, floor: float, method: str) -> MapFrame:
        """A frame for a fitted up vector: axes snapped to the world's when up is near an axis."""
        u = _unit(np.asarray(up, np.float64))
        k = int(np.argmax(np.abs(u)))
        if abs(u[k]) >= math.cos(math.radians(SNAP_DEG)):
            ax = _AXES_FOR_UP[(k, 1 if u[k] > 0 else -1)]
        else:
            ref = np.eye(3)[0] if abs(u[0]) < 0.9 else np.eye(3)[1]
            a = _unit(ref - (ref @ u) * u)
            b = np.cross(u, a)
            ax = (tuple(map(float, a)), tuple(map(float, b)))  # type: ignore[assignment]
        return cls(tuple(map(float, u)), float(floor), ax, method)  # type: ignore[arg-type]

    @property
    def basis(self) -> np.ndarray:
        """(2, 3): rows are the map's x and y axes in world coordinates."""
        return np.asarray(self.axes, np.float64)

    def to_map(self, points: np.ndarray) -> np.ndarray:
        """World points (N, 3) -> map coordinates (N, 2)."""
        return np.asarray(points, np.float64).reshape(-1, 3) @ self.basis.T

    def height(self, points: np.ndarray) -> np.ndarray:
        """World points (N, 3) -> metres above the floor."""
        return np.asarray(points, np.float64).reshape(-1, 3) @ np.asarray(self.up) - self.floor

    def heading(self, direction: np.ndarray) -> float | None:
        """Map yaw (radians, from map x towards map y) of a world direction; None when it
        points (almost) straight up or down."""
        d = self.basis @ np.asarray(direction, np.float64)
        if float(np.hypot(d[0], d[1])) < 1e-6:
            return None
        return float(math.atan2(d[1], d[0]))

    @property
    def is_world_xy(self) -> bool:
        """True when map x, y are world x, y (up is world +z, snapped)."""
        return self.axes == _AXES_FOR_UP[(2, 1)]

    def as_dict(self) -> dict[str, Any]:
        return {
            "up": list(self.up),
            "floor": self.floor,
            "axes": [list(a) for a in self.axes],
            "method": self.method,
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> MapFrame:
        try:
            up = tuple(float(v) for v in d["up"])
            axes = tuple(tuple(float(v) for v in a) for a in d["axes"])
            if len(up) != 3 or len(axes) != 2 or any(len(a) != 3 for a in axes):
                raise ValueError("up must have 3 numbers and axes two rows of 3")
            return cls(up, float(d["floor"]), axes, str(d.get("method", "")))  # type: ignore[arg-type]
        except (KeyError, TypeError, ValueError) as e:
            raise InputError(f"malformed map frame {d!r} ({e})") from e
