"""The demo's first world: four rooms with pillars showing real photographs of office things.

A Doom map holds nothing an ImageNet classifier knows, so asking the offline stack about it in
words tests nothing but its refusals. Here each pillar shows a photograph (crops of the TUM RGB-D
desk recording, CC BY 4.0: `photos/README.md`) of something with everyday words: a computer
keyboard, a monitor, a person, an office chair, a book, a game controller. The robot still
explores a simulated floor, builds its map from depth and drives to answers, so the whole loop is
the one the Doom maps run.

The questions ("Where did you see the computer keyboard?": the words are the gallery's entries
in `queries.PHRASES`) were written in everyday words before the demo was ever run on this world
and are kept fixed: do not edit them, the photos or where the pillars stand to raise a score. The
truth is where each pillar stands (`SceneObject` positions), independent of any embedder.
"""

from __future__ import annotations

import numpy as np

from .synthetic import Box, World

# kind -> its photo in `photos/`; every kind is asked about, in this order. Fixed.
PHOTOS: dict[str, str] = {
    "Keyboard": "keyboard",
    "Monitor": "monitor",
    "Person": "person",
    "OfficeChair": "chair",
    "Book": "book",
    "GameController": "gamepad",
}
# where each pillar stands (x, y metres): one or two to a room, at least 1 m from every wall
PLACES: dict[str, tuple[float, float]] = {
    "Keyboard": (6.0, 5.5),
    "Monitor": (13.0, 2.5),
    "Book": (10.5, 6.0),
    "Person": (13.5, 13.0),
    "OfficeChair": (2.5, 13.5),
    "GameController": (6.0, 10.5),
}
PILLAR_SIDE = 1.6  # metres: big enough to be recognised from 2-3 m
PILLAR_HEIGHT = 2.0  # the camera is at 0.8 m


def gallery_world() -> World:
    """16 x 16 m: four 8 x 8 m rooms joined by 1.5 m doorways, six pillars 1.6 m wide and 2 m tall
    with a photograph on every side, the robot starting in the south-west room."""
    walls = [
        (0, 0, 16, 0),
        (16, 0, 16, 16),
        (16, 16, 0, 16),
        (0, 16, 0, 0),
        (8, 0, 8, 3),
        (8, 4.5, 8, 11.5),
        (8, 13, 8, 16),
        (0, 8, 3, 8),
        (4.5, 8, 11.5, 8),
        (13, 8, 16, 8),
    ]
    boxes = [
        Box(kind, x, y, half=PILLAR_SIDE / 2, height=PILLAR_HEIGHT, color=(225, 225, 225), photo=PHOTOS[kind])
        for kind, (x, y) in PLACES.items()
    ]
    return World(np.asarray(walls, np.float64), boxes, start=(2.0, 2.0, 0.5), camera=(320, 240))
