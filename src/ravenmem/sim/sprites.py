"""Pictures of Doom objects, read from the WAD itself: the query images of "where did you see
this?" in the demo.

A Doom item is drawn as a sprite, a small paletted picture stored in the WAD; the sprite of a
thing is named by a 4-letter prefix and a frame (`SHOTA0` is the shotgun, frame A, seen from
any angle). `omgifol` (the `sim` extra) reads it; the picture is scaled up by a whole factor
and put on a plain background, like a product photo a person would show the robot.
"""

from __future__ import annotations

import functools
import os
from typing import Any

import numpy as np
from PIL import Image

from ..errors import InputError, require

# Doom (ZDoom) class name -> sprite prefix.
SPRITES: dict[str, str] = {
    "Shotgun": "SHOT",
    "SuperShotgun": "SGN2",
    "Chaingun": "MGUN",
    "RocketLauncher": "LAUN",
    "PlasmaRifle": "PLAS",
    "BFG9000": "BFUG",
    "Chainsaw": "CSAW",
    "Backpack": "BPAK",
    "Medikit": "MEDI",
    "Stimpack": "STIM",
    "GreenArmor": "ARM1",
    "BlueArmor": "ARM2",
    "ArmorBonus": "BON2",
    "HealthBonus": "BON1",
    "Soulsphere": "SOUL",
    "Megasphere": "MEGA",
    "Clip": "CLIP",
    "ClipBox": "AMMO",
    "Shell": "SHEL",
    "ShellBox": "SBOX",
    "RocketAmmo": "ROCK",
    "RocketBox": "BROK",
    "Cell": "CELL",
    "CellPack": "CELP",
    "ExplosiveBarrel": "BAR1",
    "BurningBarrel": "FCAN",
    "Column": "COLU",
    "TechLamp": "TLMP",
    "TechLamp2": "TLP2",
    "TechPillar": "ELEC",
    "TallGreenColumn": "COL1",
    "ShortGreenColumn": "COL2",
    "TallRedColumn": "COL3",
    "ShortRedColumn": "COL4",
    "Candlestick": "CAND",
    "Candelabra": "CBRA",
    "TorchTree": "TRE1",
    "BigTree": "TRE2",
    "Stalagtite": "SMIT",
    "RedTorch": "TRED",
    "BlueTorch": "TBLU",
    "GreenTorch": "TGRN",
    "RedCard": "RKEY",
    "BlueCard": "BKEY",
    "YellowCard": "YKEY",
    "RedSkull": "RSKU",
    "BlueSkull": "BSKU",
    "YellowSkull": "YSKU",
    "RadSuit": "SUIT",
    "Allmap": "PMAP",
    "Infrared": "PVIS",
}


def freedoom_wad(name: str = "freedoom2") -> str:
    """Path of a WAD that ships inside the `vizdoom` package."""
    vzd = require("vizdoom", "sim")
    return os.path.join(os.path.dirname(vzd.__file__), f"{name}.wad")  # type: ignore[attr-defined]


@functools.lru_cache(maxsize=4)
def _wad(path: str) -> Any:
    omg = require("omg", "sim")
    try:
        return omg.WAD(path)  # type: ignore[attr-defined]
    except Exception as e:  # omgifol raises plain exceptions for unreadable files
        raise InputError(f"{path}: not a readable WAD ({e})") from e


def has_sprite(kind: str, wad: str | None = None) -> bool:
    """Whether the WAD holds a picture of this kind of object."""
    prefix = SPRITES.get(kind)
    if prefix is None:
        return False
    sprites = _wad(wad or freedoom_wad()).sprites
    return any(f"{prefix}A{r}" in sprites for r in "01")


def sprite_image(
    kind: str,
    wad: str | None = None,
    size: tuple[int, int] = (160, 120),
    fill: float = 0.7,
    background: tuple[int, int, int] = (90, 90, 90),
) -> np.ndarray:
    """An RGB picture (height, width = size[1], size[0]) of an object kind: its sprite, scaled
    up by a whole factor to fill about `fill` of the picture, on a plain background."""
    prefix = SPRITES.get(kind)
    if prefix is None:
        raise InputError(f"no sprite known for {kind!r}")
    sprites = _wad(wad or freedoom_wad()).sprites
    name = next((f"{prefix}A{r}" for r in "01" if f"{prefix}A{r}" in sprites), None)
    if name is None:
        raise InputError(f"the WAD has no sprite {prefix}A0/A1 for {kind!r}")
    spr = sprites[name].to_Image("RGBA")
    w, h = size
    k = max(1, int(min(fill * w / spr.width, fill * h / spr.height)))
    spr = spr.resize((spr.width * k, spr.height * k), Image.Resampling.NEAREST)
    canvas = Image.new("RGB", size, background)
    canvas.paste(spr, ((w - spr.width) // 2, (h - spr.height) // 2), spr)
    return np.asarray(canvas, np.uint8).copy()
