"""Contact sheets: the hits of a search (or the evidence of an answer) as one PNG, thumbnail,
rank, score, time and pose per cell: the quickest way for a person to see right and wrong hits.

`sheet_layout` is pure geometry (where the title and each cell go), so callers and tests know
exactly where every cell is drawn; `draw_sheet` draws the cells there and writes the PNG
crash-safely. Rows are the one hit shape (`tools.hit_json`, or an answer's evidence).
"""

from __future__ import annotations

import io
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from PIL import Image, ImageDraw, ImageFont
from PIL.PngImagePlugin import PngInfo

from ..errors import InputError, NotFoundError
from ..fsio import PICTURE_TAG, atomic_open
from ..timeparse import fmt_time

BACKGROUND = (255, 255, 255)
BORDER = (40, 40, 48)
TEXT = (20, 20, 20)
MUTED = (110, 110, 120)
BADGE = (200, 30, 40)
NO_IMAGE = (225, 225, 230)

Box = tuple[int, int, int, int]  # left, top, right, bottom (right/bottom exclusive)


@dataclass(frozen=True)
class SheetLayout:
    """Where everything goes: the sheet size, the title band and, per cell, its outer box (the
    border is drawn on its edge) and the box the thumbnail is fitted into."""

    width: int
    height: int
    title: Box
    cells: list[Box] = field(default_factory=list)
    thumbs: list[Box] = field(default_factory=list)
    border: int = 2


@dataclass
class Cell:
    """One picture and the lines printed under it; `badge` goes on the picture (the rank)."""

    image: np.ndarray | None
    lines: list[str]
    badge: str = ""


def sheet_layout(
    n: int,
    cols: int | None = None,
    thumb: tuple[int, int] = (256, 192),
    text_lines: int = 4,
    line_height: int = 16,
    gap: int = 10,
    title_lines: int = 2,
    min_width: int = 800,
) -> SheetLayout:
    """The geometry of a sheet of n cells (cols: at most 4 per row unless given); n = 0 is a
    sheet with its title only (a search with no hits still gets its picture)."""
    if n < 0:
        raise InputError(f"a contact sheet cannot have {n} pictures")
    cols = max(1, min(cols or 4, n))
    rows = math.ceil(n / cols)  # no cells: the title band alone says so
    border, pad = 2, 4
    tw, th = thumb
    cw = tw + 2 * (border + pad)
    ch = th + text_lines * line_height + 2 * (border + pad) + pad
    title_h = title_lines * (line_height + 4) + gap
    width = max(gap + cols * (cw + gap), min_width)  # room for the title even with one cell
    height = title_h + gap + rows * (ch + gap)
    cells, thumbs = [], []
    for i in range(n):
        r, c = divmod(i, cols)
        x0 = gap + c * (cw + gap)
        y0 = title_h + gap + r * (ch + gap)
        cells.append((x0, y0, x0 + cw, y0 + ch))
        tx, ty = x0 + border + pad, y0 + border + pad
        thumbs.append((tx, ty, tx + tw, ty + th))
    return SheetLayout(width, height, (gap, gap, width - gap, title_h), cells, thumbs, border)


def fit(box: Box, w: int, h: int) -> Box:
    """The largest box of aspect w:h centred in `box` (where a picture of w x h is drawn)."""
    bw, bh = box[2] - box[0], box[3] - box[1]
    s = min(bw / w, bh / h)
    fw, fh = max(1, round(w * s)), max(1, round(h * s))
    x0 = box[0] + (bw - fw) // 2
    y0 = box[1] + (bh - fh) // 2
    return (x0, y0, x0 + fw, y0 + fh)


def _font(size: int) -> ImageFont.FreeTypeFont | ImageFont.ImageFont:
    try:
        return ImageFont.load_default(size=size)
    except (TypeError, ImportError, OSError):  # Pillow < 10.1, or without FreeType
        return ImageFont.load_default()


def _clip(draw: ImageDraw.ImageDraw, text: str, font: Any, width: int) -> str:
    """The text, shortened with '…' to fit `width` pixels."""
    if draw.textlength(text, font=font) <= width:
        return text
    while text and draw.textlength(text + "…", font=font) > width:
        text = text[:-1]
    return text + "…"


def draw_sheet(
    cells: Sequence[Cell], out: str | Path, title: Sequence[str] = (), cols: int | None = None
) -> SheetLayout:
    """Draw the cells (in order, row by row) and write the PNG to `out`; returns the layout."""
    layout = sheet_layout(len(cells), cols=cols)
    im = Image.new("RGB", (layout.width, layout.height), BACKGROUND)
    draw = ImageDraw.Draw(im)
    font, bold = _font(13), _font(15)
    tx0, ty0, tx1, _ = layout.title
    for i, line in enumerate(list(title)[:2]):
        draw.text(
            (tx0, ty0 + i * 20),
            _clip(draw, line, bold if i == 0 else font, tx1 - tx0),
            fill=TEXT,
            font=bold if i == 0 else font,
        )
    if not cells:
        draw.text((tx0, ty0 + 40), "no hits", fill=MUTED, font=font)
    for cell, box, tbox in zip(cells, layout.cells, layout.thumbs):
        draw.rectangle((box[0], box[1], box[2] - 1, box[3] - 1), outline=BORDER, width=layout.border)
        if cell.image is None:
            draw.rectangle((tbox[0], tbox[1], tbox[2] - 1, tbox[3] - 1), fill=NO_IMAGE)
            draw.text((tbox[0] + 8, tbox[1] + 8), "no image", fill=MUTED, font=font)
        else:
            h, w = cell.image.shape[:2]
            fb = fit(tbox, w, h)
            pic = Image.fromarray(cell.image).resize(
                (fb[2] - fb[0], fb[3] - fb[1]), Image.Resampling.BILINEAR
            )
            im.paste(pic, (fb[0], fb[1]))
        if cell.badge:
            bw = int(draw.textlength(cell.badge, font=bold)) + 10
            draw.rectangle((tbox[0], tbox[1], tbox[0] + bw, tbox[1] + 20), fill=BADGE)
            draw.text((tbox[0] + 5, tbox[1] + 2), cell.badge, fill=BACKGROUND, font=bold)
        y = tbox[3] + 4
        for j, line in enumerate(cell.lines[:4]):
            draw.text(
                (tbox[0], y + j * 16),
                _clip(draw, line, font, tbox[2] - tbox[0]),
                fill=TEXT if j == 0 else MUTED,
                font=font,
            )
    tag = PngInfo()
    tag.add_text(*PICTURE_TAG)  # a later --force may replace only such a file
    try:
        with atomic_open(out) as f:  # a new file renamed into place: never through a symlink
            im.save(f, format="PNG", pnginfo=tag)
    except OSError as e:
        raise InputError(f"cannot write the contact sheet {out}: {e.strerror or e}") from None
    return layout


def decode_picture(data: bytes | None) -> np.ndarray | None:
    """RGB from JPEG/PNG bytes (a picture fetched from a service), None when it does not decode."""
    if not data:
        return None
    try:
        with Image.open(io.BytesIO(data)) as im:
            return np.asarray(im.convert("RGB"), dtype=np.uint8)
    except Exception:  # decoders raise many kinds (and DecompressionBombError): no picture then
        return None


def hit_cells(
    rows: Sequence[dict[str, Any]],
    load: Callable[[dict[str, Any]], np.ndarray | None],
    t0: float | None = None,
) -> list[Cell]:
    """Cells for rows in the hit shape (`tools.hit_json`) or an answer's evidence: rank, id,
    score or distance, time (and seconds since `t0`, the memory's first, when known), position
    and heading, and any text read in the picture."""
    cells = []
    for i, r in enumerate(rows):
        rank = r.get("rank") or i + 1
        head = [f"#{rank}", f"id {r['id']}"]
        if r.get("score") is not None:
            head.append(f"score {float(r['score']):.3f}")
        if r.get("distance") is not None:
            head.append(f"{float(r['distance']):.2f} m away")
        if r.get("ocr_match"):
            head.append("text match")
        t = float(r["t"])
        off = r.get("offset_s", None if t0 is None else t - t0)
        when = fmt_time(t) + ("" if off is None else f"  (+{float(off):.1f} s)")
        yaw = (
            float(r["yaw_deg"]) if r.get("yaw_deg") is not None else math.degrees(float(r.get("yaw") or 0.0))
        )
        lines = [
            "  ".join(head),
            when,
            f"x {float(r['x']):.2f}  y {float(r['y']):.2f}  z {float(r.get('z') or 0.0):.2f} m  yaw {yaw:.0f}°",
        ]
        if r.get("ocr_text"):
            lines.append(f"text: {r['ocr_text']}")
        cells.append(Cell(load(r), lines, badge=str(rank)))
    return cells


def search_sheet(
    mem: Any, hits: Sequence[Any], rows: Sequence[dict[str, Any]], out: str | Path, what: str, order: str
) -> SheetLayout:
    """The sheet of a search: `rows` are the hits in the `hit_json` shape, pictures from the
    memory (only files inside its folder, as `Memory.load_image` allows)."""
    recs = {h.memory.id: h.memory for h in hits}
    title = [what, f"{len(rows)} hit(s), {order}  |  memory {Path(mem.path).name}"]
    return draw_sheet(hit_cells(rows, lambda r: mem.load_image(recs[r["id"]])), out, title)


def remote_sheet(
    rows: Sequence[dict[str, Any]],
    fetch: Callable[[int], bytes | None],
    out: str | Path,
    title: Sequence[str],
    t0: float | None = None,
) -> SheetLayout:
    """A sheet of hits or evidence from a running service: `fetch(id)` gives a memory's picture."""
    return draw_sheet(hit_cells(rows, lambda r: decode_picture(fetch(int(r["id"]))), t0), out, title)


def answer_title(answer: dict[str, Any]) -> list[str]:
    """The question and the answer, as a sheet's two title lines."""
    status = "FAILED" if answer.get("failed") else ("found" if answer.get("found") else "not found")
    return [f"Q: {answer.get('question', '')}", f"A ({status}): {answer.get('text', '')}"]


def answer_sheet(mem: Any, answer: dict[str, Any], out: str | Path) -> SheetLayout:
    """The sheet of an answer: its evidence memories, under the question and the answer."""
    ev = list(answer.get("evidence") or [])
    try:
        recs = {r.id: r for r in mem.get([e["id"] for e in ev])} if ev else {}
    except NotFoundError:  # evidence naming a memory that is gone: drawn without its picture
        recs = {}
    t0 = mem.time_span()[0] if mem.count() else None

    def load(r: dict[str, Any]) -> np.ndarray | None:
        rec = recs.get(r["id"])
        return None if rec is None else mem.load_image(rec)

    return draw_sheet(hit_cells(ev, load, t0), out, answer_title(answer))
