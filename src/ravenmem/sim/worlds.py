"""The built-in worlds of the synthetic robot, and `synthetic:NAME` environments made from them.

Apart from `ravenmem.sim.synthetic` (the renderer and the robot, with only their default world,
`rooms`) so that a world built on them, such as the photo `gallery`, imports the renderer and
never the other way round. `synthetic:rooms` (the default) and `synthetic:gallery` are the names.
"""

from __future__ import annotations

from collections.abc import Callable

from ..errors import InputError
from .base import ENVIRONMENTS
from .gallery import gallery_world
from .synthetic import SyntheticEnv, World, rooms_world

__all__ = ["WORLDS"]


WORLDS: dict[str, Callable[[], World]] = {"rooms": rooms_world, "gallery": gallery_world}


@ENVIRONMENTS.register("synthetic")
def _make_synthetic(spec: str = "", **kwargs: object) -> SyntheticEnv:
    name = spec or "rooms"
    if name not in WORLDS:
        raise InputError(f"synthetic:{name}: unknown world; choose one of: {', '.join(sorted(WORLDS))}")
    return SyntheticEnv(WORLDS[name](), name=f"synthetic:{name}", **kwargs)  # type: ignore[arg-type]
