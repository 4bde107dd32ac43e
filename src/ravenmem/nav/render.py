"""The map picture a person reads: occupancy, explored area, trajectory, memories, answers and
planned paths, in metres, with a legend and a scale bar."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..fsio import PICTURE_TAG
from .grid import OccupancyGrid

UNKNOWN, FREE, EXPLORED, OCCUPIED = (
    (0.78, 0.78, 0.78),
    (0.97, 0.97, 0.97),
    (0.80, 0.90, 1.0),
    (0.12, 0.12, 0.12),
)
LEDGE = (0.55, 0.35, 0.20)


@dataclass
class MapLayers:
    """Everything drawn over the grid, all in world metres."""

    trajectory: list[tuple[float, float]] = field(default_factory=list)
    memories: list[tuple[float, float]] = field(default_factory=list)
    truths: list[tuple[str, float, float]] = field(default_factory=list)  # (label, x, y)
    answers: list[tuple[str, float, float, bool]] = field(default_factory=list)  # (method, x, y, success)
    paths: list[list[tuple[float, float]]] = field(default_factory=list)
    drives: list[list[tuple[float, float]]] = field(default_factory=list)  # Phase II trajectories
    goals: list[tuple[float, float, float]] = field(default_factory=list)  # goal poses (x, y, yaw)
    start: tuple[float, float] | None = None
    title: str = ""


def grid_rgb(grid: OccupancyGrid) -> np.ndarray:
    """(H, W, 3) float image: unknown grey, free white, explored light blue, occupied black,
    ledges brown."""
    img = np.empty((*grid.shape, 3), np.float32)
    img[:] = UNKNOWN
    img[grid.free] = FREE
    img[grid.free & grid.explored] = EXPLORED
    img[grid.ledges() & ~grid.occupied] = LEDGE
    img[grid.occupied] = OCCUPIED
    return img


def _nice_length(span: float) -> float:
    """A round scale-bar length near a fifth of the span."""
    target = max(span / 5.0, 1e-3)
    base = 10 ** np.floor(np.log10(target))
    for m in (5, 2, 1):
        if m * base <= target:
            return float(m * base)
    return float(base)


_RINGS_PT = (5.0, 13.0, 22.0, 32.0, 44.0)  # label offsets tried, nearest first (points)
_DIRECTIONS = [(np.cos(a), np.sin(a)) for a in np.radians([-30, 30, 150, 210, 90, 270, 0, 180])]


def place_labels(
    ax: Any, items: list[tuple[str, float, float]], color: str, fontsize: float = 6.0, merge_pt: float = 10.0
) -> list[Any]:
    """Name points on `ax` so that no two names overlap: points of one name closer than
    `merge_pt` share one label; each label takes the first free spot of rings of offsets around
    its point (nearest ring first, a thin leader line beyond the first), else the spot that
    overlaps least. Returns the text artists (their boxes are checked by the tests)."""
    fig = ax.figure
    fig.canvas.draw()  # a renderer, and data -> display coordinates as they will be saved
    renderer = fig.canvas.get_renderer()
    to_px = ax.transData.transform
    pt = fig.dpi / 72.0
    groups: list[tuple[str, np.ndarray]] = []
    for label, x, y in items:
        p = to_px((x, y))
        if not any(name == label and np.hypot(*(q - p)) < merge_pt * pt for name, q in groups):
            groups.append((label, p))
    placed: list[Any] = []  # Bbox of every label placed so far
    texts = []
    for label, p in groups:
        x, y = ax.transData.inverted().transform(p)
        best: tuple[float, Any] | None = None
        for ring in _RINGS_PT:
            for dx, dy in _DIRECTIONS:
                t = ax.annotate(
                    label,
                    (x, y),
                    xytext=(ring * dx, ring * dy),
                    textcoords="offset points",
                    fontsize=fontsize,
                    color=color,
                    ha="left" if dx > 0.1 else "right" if dx < -0.1 else "center",
                    va="bottom" if dy > 0.1 else "top" if dy < -0.1 else "center",
                    arrowprops={"arrowstyle": "-", "color": color, "lw": 0.4, "alpha": 0.7}
                    if ring > _RINGS_PT[0]
                    else None,
                    zorder=8,
                )
                box = t.get_window_extent(renderer).expanded(1.05, 1.1)
                overlap = sum(_area(box, b) for b in placed) + _outside(box, ax.bbox)
                if best is None or overlap < best[0]:
                    if best is not None:
                        best[1].remove()
                    best = (overlap, t)
                else:
                    t.remove()
                if overlap == 0:
                    break
            if best is not None and best[0] == 0:
                break
        assert best is not None
        placed.append(best[1].get_window_extent(renderer).expanded(1.05, 1.1))
        texts.append(best[1])
    return texts


def _area(a: Any, b: Any) -> float:
    """The area two display boxes share."""
    w = min(a.x1, b.x1) - max(a.x0, b.x0)
    h = min(a.y1, b.y1) - max(a.y0, b.y0)
    return float(w * h) if w > 0 and h > 0 else 0.0


def _outside(box: Any, frame: Any) -> float:
    """How much of a box lies outside the axes (a label cut off by the frame is unreadable)."""
    return float(box.width * box.height) - _area(box, frame)


def draw_map(grid: OccupancyGrid, layers: MapLayers, path: str | Path, dpi: int = 130) -> Path:
    """Write the map PNG to `path` (cropped to the known area) and return the path."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    r0, r1, c0, c1, ext = _crop(grid)
    w_m, h_m = ext[1] - ext[0], ext[3] - ext[2]
    scale = 9.0 / max(w_m, h_m, 1e-6)
    fig, ax = plt.subplots(figsize=(max(5.0, w_m * scale) + 3.2, max(4.0, h_m * scale) + 0.8))
    img = grid_rgb(grid)[r0:r1, c0:c1]
    ax.imshow(img, origin="lower", extent=ext, interpolation="nearest")
    handles = _floor_legend(img)
    handles += _draw_tracks(ax, layers)
    handles += _draw_answers(ax, layers)
    handles += _draw_poses(ax, layers, max(grid.resolution * 4, 0.04 * max(w_m, h_m)))
    _frame(ax, grid.resolution, ext, layers.title)
    ax.legend(handles=handles, loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8, frameon=False)
    fig.tight_layout()
    if layers.truths:  # last: placing needs the final layout (limits, aspect, margins)
        place_labels(ax, layers.truths, color="#d62728")
    out = Path(path)
    fig.savefig(out, dpi=dpi, metadata=dict([PICTURE_TAG]))  # a later --force may replace only such a file
    plt.close(fig)
    return out


def _crop(grid: OccupancyGrid) -> tuple[int, int, int, int, tuple[float, float, float, float]]:
    """Rows and columns of the known area (plus a margin) and their extent in metres."""
    x0, x1, y0, y1 = grid.extent()
    rr, cc = np.nonzero(grid.known)
    if rr.size:
        pad = 4
        r0, r1 = max(0, rr.min() - pad), min(grid.shape[0], rr.max() + pad + 1)
        c0, c1 = max(0, cc.min() - pad), min(grid.shape[1], cc.max() + pad + 1)
    else:
        r0, r1, c0, c1 = 0, grid.shape[0], 0, grid.shape[1]
    res = grid.resolution
    return r0, r1, c0, c1, (x0 + c0 * res, x0 + c1 * res, y0 + r0 * res, y0 + r1 * res)


def _floor_legend(img: np.ndarray) -> list:
    """Legend entries for the kinds of cell the picture shows."""
    from matplotlib.patches import Patch

    handles: list = [Patch(color=UNKNOWN, label="unknown")]
    for colour, label in (
        (FREE, "free, seen from afar"),
        (EXPLORED, "explored free"),
        (LEDGE, "ledge (floor step)"),
    ):
        if np.all(img == np.asarray(colour, np.float32), axis=-1).any():
            handles.append(Patch(color=colour, label=label))
    handles.append(Patch(color=OCCUPIED, label="obstacle"))
    return handles


def _draw_tracks(ax: Any, layers: MapLayers) -> list:
    """The trajectory, the memories, planned paths, drives and true objects; legend entries."""
    from matplotlib.lines import Line2D

    handles: list = []
    if layers.trajectory:
        t = np.asarray(layers.trajectory)
        ax.plot(t[:, 0], t[:, 1], color="#f28e2b", lw=1.0, alpha=0.9)
        handles.append(Line2D([], [], color="#f28e2b", label="trajectory"))
    if layers.memories:
        m = np.asarray(layers.memories)
        ax.scatter(m[:, 0], m[:, 1], s=6, color="#7b3294", zorder=3)
        handles.append(Line2D([], [], ls="", marker="o", ms=3, color="#7b3294", label=f"memories ({len(m)})"))
    for p in layers.paths:
        if len(p) > 1:
            a = np.asarray(p)
            ax.plot(a[:, 0], a[:, 1], color="#1f77b4", lw=1.4, ls="--", zorder=4)
    if layers.paths:
        handles.append(Line2D([], [], color="#1f77b4", ls="--", label="planned path (A*)"))
    for d in layers.drives:
        if len(d) > 1:
            a = np.asarray(d)
            ax.plot(a[:, 0], a[:, 1], color="#2ca02c", lw=1.2, alpha=0.9, zorder=4)
    if any(len(d) > 1 for d in layers.drives):
        handles.append(Line2D([], [], color="#2ca02c", label="driven to answers"))
    if layers.truths:
        tr = np.asarray([(x, y) for _, x, y in layers.truths])
        ax.scatter(tr[:, 0], tr[:, 1], marker="x", s=28, color="#d62728", linewidths=1.2, zorder=5)
        handles.append(Line2D([], [], ls="", marker="x", color="#d62728", label="true object (named)"))
    return handles


def _draw_answers(ax: Any, layers: MapLayers) -> list:
    """Answers, one marker shape per group, green when the robot got there; legend entries."""
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    handles: list = []
    shapes = ("*", "s", "D", "^", "v", "P", "X")
    groups = list(dict.fromkeys(label for label, *_ in layers.answers))
    for gi, group in enumerate(groups):
        pts = [(x, y, ok) for label, x, y, ok in layers.answers if label == group]
        marker = shapes[gi % len(shapes)]
        for x, y, ok in pts:
            ax.scatter(
                [x],
                [y],
                marker=marker,
                s=110 if marker == "*" else 45,
                color="#2ca02c" if ok else "#ff7f0e",
                edgecolors="black",
                linewidths=0.5,
                zorder=6,
            )
        handles.append(
            Line2D([], [], ls="", marker=marker, ms=8, color="#bbbbbb", mec="black", label=f"answer: {group}")
        )
    if layers.answers:
        handles += [
            Patch(color="#2ca02c", label="answer: robot got within the radius"),
            Patch(color="#ff7f0e", label="answer: robot did not"),
        ]
    return handles


def _draw_poses(ax: Any, layers: MapLayers, size: float) -> list:
    """Goal poses as arrows `size` metres long, and the start; legend entries."""
    from matplotlib.lines import Line2D

    handles: list = []
    for x, y, yaw in layers.goals:
        ax.annotate(
            "",
            (x + size * np.cos(yaw), y + size * np.sin(yaw)),
            (x, y),
            arrowprops={"arrowstyle": "-|>", "color": "#9467bd", "lw": 1.8},
            zorder=7,
        )
    if layers.goals:
        handles.append(Line2D([], [], color="#9467bd", marker=">", label="goal pose (heading)"))
    if layers.start is not None:
        ax.scatter(
            [layers.start[0]],
            [layers.start[1]],
            marker="^",
            s=70,
            color="#17becf",
            edgecolors="black",
            zorder=6,
        )
        handles.append(Line2D([], [], ls="", marker="^", color="#17becf", mec="black", label="start"))
    return handles


def _frame(ax: Any, res: float, ext: tuple[float, float, float, float], title: str | None) -> None:
    """Scale bar, limits, equal aspect, axis labels and the title."""
    from mpl_toolkits.axes_grid1.anchored_artists import AnchoredSizeBar

    w_m, h_m = ext[1] - ext[0], ext[3] - ext[2]
    bar = _nice_length(w_m)
    ax.add_artist(
        AnchoredSizeBar(
            ax.transData,
            bar,
            f"{bar:g} m",
            "lower right",
            pad=0.4,
            sep=3,
            frameon=True,
            size_vertical=max(res, h_m / 150),
        )
    )
    ax.set_xlim(ext[0], ext[1])
    ax.set_ylim(ext[2], ext[3])
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    if title:
        ax.set_title(title, fontsize=9)
