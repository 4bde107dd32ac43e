"""Demo queries from a simulator's ground-truth objects, in words a person would use, and the
success measure of the paper: an answer (or the place the robot drove to) succeeds when it is
within `radius` metres of the nearest true instance of the object asked about."""

from __future__ import annotations

import math
import re
from collections import Counter
from collections.abc import Iterable
from dataclasses import dataclass

from .base import SceneObject

# Doom (ZDoom/Freedoom) class names -> what a person would call them.
PHRASES: dict[str, str] = {
    "ExplosiveBarrel": "explosive barrel",
    "BurningBarrel": "burning barrel",
    "Chainsaw": "chainsaw",
    "Shotgun": "shotgun",
    "SuperShotgun": "double-barrelled shotgun",
    "Chaingun": "chaingun",
    "RocketLauncher": "rocket launcher",
    "PlasmaRifle": "plasma rifle",
    "BFG9000": "big energy gun",
    "Pistol": "pistol",
    "Backpack": "backpack",
    "Medikit": "first aid kit",
    "Stimpack": "small medical kit",
    "GreenArmor": "green armor vest",
    "BlueArmor": "blue armor vest",
    "ArmorBonus": "small armor helmet",
    "HealthBonus": "small health potion",
    "Soulsphere": "glowing blue sphere",
    "Megasphere": "glowing sphere",
    "Clip": "ammunition clip",
    "ClipBox": "box of bullets",
    "Shell": "shotgun shells",
    "ShellBox": "box of shotgun shells",
    "RocketAmmo": "rocket",
    "RocketBox": "box of rockets",
    "Cell": "energy cell",
    "CellPack": "energy cell pack",
    "Column": "floor lamp",
    "TechLamp": "tall lamp",
    "TechLamp2": "short lamp",
    "TechPillar": "metal pillar",
    "TallGreenColumn": "tall green column",
    "ShortGreenColumn": "short green column",
    "TallRedColumn": "tall red column",
    "ShortRedColumn": "short red column",
    "Candlestick": "candlestick",
    "Candelabra": "candelabra",
    "TorchTree": "burnt tree",
    "BigTree": "large tree",
    "Stalagtite": "stalagmite",
    "RedTorch": "tall red torch",
    "BlueTorch": "tall blue torch",
    "GreenTorch": "tall green torch",
    "RedCard": "red keycard",
    "BlueCard": "blue keycard",
    "YellowCard": "yellow keycard",
    "RedSkull": "red skull key",
    "BlueSkull": "blue skull key",
    "YellowSkull": "yellow skull key",
    "RadSuit": "radiation suit",
    "Allmap": "computer map",
    "Infrared": "light amplification visor",
    "DeadMarine": "dead soldier",
    # the gallery world (`sim/gallery.py`): written before the demo ran on it, fixed
    "Keyboard": "computer keyboard",
    "Monitor": "computer monitor",
    "Person": "person",
    "OfficeChair": "office chair",
    "Book": "book",
    "GameController": "game controller",
    "RedBox": "red box",
    "BlueBox": "blue box",
    "GreenBox": "green box",
}
# Kinds an ImageNet-label embedder could plausibly find (it knows barrels, chainsaws, rifles,
# backpacks, lamps, ...) come first; gore and monster corpses are never asked about.
PREFERRED = (
    "ExplosiveBarrel",
    "BurningBarrel",
    "Chainsaw",
    "Shotgun",
    "SuperShotgun",
    "Chaingun",
    "RocketLauncher",
    "Backpack",
    "Medikit",
    "GreenArmor",
    "BlueArmor",
    "Column",
    "TechLamp",
    "TechPillar",
    "Candelabra",
    "BigTree",
    "TorchTree",
    "Soulsphere",
    "RedCard",
    "BlueCard",
    "YellowCard",
    "Stimpack",
    "RedBox",
    "BlueBox",
    "GreenBox",
)
NEVER = re.compile(
    r"^(Dead|Gibbed|Gibs|ColonGibs|Hang|Meat|BloodyTwitch|HeadOn|HeadsOn|Heart|Skull|Body|"
    r"SmallBlood|BrainStem|Teleport|MapSpot|PlayerStart)"
)


def phrase_for(kind: str) -> str:
    """Human words for a class name; unknown CamelCase names are split ('GreenArmor' -> 'green armor')."""
    if kind in PHRASES:
        return PHRASES[kind]
    return " ".join(w.lower() for w in re.findall(r"[A-Z]?[a-z]+|[A-Z]+(?![a-z])|\d+", kind)) or kind


@dataclass(frozen=True)
class DemoQuery:
    kind: str
    phrase: str
    question: str
    instances: tuple[tuple[float, float], ...]

    def nearest(self, x: float, y: float) -> float:
        """Planar distance (m) from (x, y) to the nearest true instance."""
        return min(math.hypot(x - ix, y - iy) for ix, iy in self.instances)


def make_queries(
    objects: Iterable[SceneObject],
    seen: set[int] | None = None,
    max_queries: int = 8,
    kinds: list[str] | None = None,
) -> list[DemoQuery]:
    """One query per object kind that the robot saw at least once (all kinds when `seen` is None),
    preferred kinds first, then the rarest; `kinds` picks them explicitly instead."""
    objs = list(objects)
    by_kind: dict[str, list[SceneObject]] = {}
    for o in objs:
        by_kind.setdefault(o.kind, []).append(o)
    seen_kinds = Counter(o.kind for o in objs if seen is None or o.id in seen)
    if kinds is None:
        cands = [k for k in seen_kinds if not NEVER.match(k)]
        pref = [k for k in PREFERRED if k in cands]
        rest = sorted((k for k in cands if k not in pref), key=lambda k: (len(by_kind[k]), k))
        kinds = (pref + rest)[:max_queries]
    out = []
    for k in kinds:
        if k not in by_kind:
            continue
        phrase = phrase_for(k)
        out.append(
            DemoQuery(k, phrase, f"Where did you see the {phrase}?", tuple((o.x, o.y) for o in by_kind[k]))
        )
    return out


def match_kind(text: str, kinds: Iterable[str]) -> str | None:
    """The object kind a free-text query names ('the explosive barrel' -> 'ExplosiveBarrel'),
    for scoring `ravenmem navigate` against ground truth; None when no kind's words all appear."""
    words = set(re.findall(r"[a-z0-9]+", text.lower()))
    best: tuple[int, str] | None = None
    for k in set(kinds):
        for cand in (phrase_for(k), k.lower()):
            need = set(re.findall(r"[a-z0-9]+", cand.lower()))
            if need and need <= words and (best is None or len(need) > best[0]):
                best = (len(need), k)
    return best[1] if best else None
