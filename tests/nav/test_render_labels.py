"""Object names on the map picture never overlap one another: crowded names move to free spots
(with a leader line), and points of one name close together share one label."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from PIL import Image

from ravenmem.nav.grid import MapConfig, OccupancyGrid
from ravenmem.nav.render import MapLayers, _area, draw_map, place_labels

NAMES = [
    "explosive barrel",
    "shotgun",
    "floor lamp",
    "ammunition clip",
    "small health potion",
    "armor helmet",
]


def crowded() -> list[tuple[str, float, float]]:
    """Six names within half a metre of each other, and three instances of one name together."""
    rng = np.random.default_rng(0)
    items = [(n, 5.0 + rng.uniform(-0.25, 0.25), 5.0 + rng.uniform(-0.25, 0.25)) for n in NAMES]
    return items + [("shotgun", 8.0, 2.0), ("shotgun", 8.05, 2.02), ("shotgun", 8.02, 1.97)]


def boxes(texts) -> list:
    renderer = texts[0].figure.canvas.get_renderer()
    return [t.get_window_extent(renderer) for t in texts]


def test_crowded_names_do_not_collide() -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(4, 3))
    ax.set_xlim(0, 10)
    ax.set_ylim(0, 10)
    texts = place_labels(ax, crowded(), color="red")
    assert sorted(t.get_text() for t in texts) == sorted([*NAMES, "shotgun"])  # 3 shotguns, one label
    bb = boxes(texts)
    assert all(_area(a, b) == 0 for i, a in enumerate(bb) for b in bb[i + 1 :])
    assert all(ax.bbox.x0 <= b.x0 and b.x1 <= ax.bbox.x1 for b in bb)  # none cut off by the frame
    # the way it was: every name at one offset from its point, piled on each other
    ax2 = plt.subplots(figsize=(4, 3))[1]
    ax2.set_xlim(0, 10)
    ax2.set_ylim(0, 10)
    old = [
        ax2.annotate(n, (x, y), xytext=(3, -8), textcoords="offset points", fontsize=6)
        for n, x, y in crowded()
    ]
    ax2.figure.canvas.draw()
    ob = boxes(old)
    assert any(_area(a, b) > 0 for i, a in enumerate(ob) for b in ob[i + 1 :])
    plt.close("all")


def test_the_map_picture_with_crowded_names(tmp_path: Path) -> None:
    grid = OccupancyGrid(MapConfig(resolution=0.1), origin=(0.0, 0.0), shape=(100, 100))
    grid.known[10:90, 10:90] = True
    grid.logodds[10:90, 10:90] = -1.0  # free
    grid.logodds[10:14, 10:90] = 2.0  # a wall
    out = draw_map(grid, MapLayers(truths=crowded(), title="crowded"), tmp_path / "map.png")
    assert Image.open(out).size[0] > 300
