"""The map picture a person reads: occupancy, explored area, trajectory, memories, answers and
planned paths, in metres, with a legend and a scale bar."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

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


def draw_map(grid: OccupancyGrid, layers: MapLayers, path: str | Path, dpi: int = 130) -> Path:
    """Write the map PNG to `path` (cropped to the known area) and return the path."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch
    from mpl_toolkits.axes_grid1.anchored_artists import AnchoredSizeBar

    x0, x1, y0, y1 = grid.extent()
    rr, cc = np.nonzero(grid.known)
    if rr.size:
        pad = 4
        r0, r1 = max(0, rr.min() - pad), min(grid.shape[0], rr.max() + pad + 1)
        c0, c1 = max(0, cc.min() - pad), min(grid.shape[1], cc.max() + pad + 1)
    else:
        r0, r1, c0, c1 = 0, grid.shape[0], 0, grid.shape[1]
    res = grid.resolution
    ext = (x0 + c0 * res, x0 + c1 * res, y0 + r0 * res, y0 + r1 * res)
    w_m, h_m = ext[1] - ext[0], ext[3] - ext[2]
    scale = 9.0 / max(w_m, h_m, 1e-6)
    fig, ax = plt.subplots(figsize=(max(5.0, w_m * scale) + 3.2, max(4.0, h_m * scale) + 0.8))
    img = grid_rgb(grid)[r0:r1, c0:c1]
    ax.imshow(img, origin="lower", extent=ext, interpolation="nearest")
    handles: list = [Patch(color=UNKNOWN, label="unknown")]
    for colour, label in (
        (FREE, "free, seen from afar"),
        (EXPLORED, "explored free"),
        (LEDGE, "ledge (floor step)"),
    ):
        if np.all(img == np.asarray(colour, np.float32), axis=-1).any():
            handles.append(Patch(color=colour, label=label))
    handles.append(Patch(color=OCCUPIED, label="obstacle"))
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
        for label, x, y in layers.truths:
            ax.annotate(
                label, (x, y), xytext=(3, -8), textcoords="offset points", fontsize=6, color="#d62728"
            )
        handles.append(Line2D([], [], ls="", marker="x", color="#d62728", label="true object (named)"))
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
    for x, y, yaw in layers.goals:
        size = max(res * 4, 0.04 * max(w_m, h_m))
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
    if layers.title:
        ax.set_title(layers.title, fontsize=9)
    ax.legend(handles=handles, loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8, frameon=False)
    fig.tight_layout()
    out = Path(path)
    fig.savefig(out, dpi=dpi, metadata=dict([PICTURE_TAG]))  # a later --force may replace only such a file
    plt.close(fig)
    return out
