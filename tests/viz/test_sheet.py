"""Contact sheets through the real command: `search --sheet` and `ask --sheet`."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from PIL import Image

import ravenmem
from ravenmem.imageio import read_image
from ravenmem.timeparse import fmt_time
from ravenmem.viz.sheet import BACKGROUND, BORDER, SheetLayout, fit, sheet_layout
from tests.cli.helpers import assert_one_line_error

from .helpers import T0, cli, cli_json, make_memory


@pytest.fixture(scope="module")
def memory(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return make_memory(tmp_path_factory.mktemp("sheet") / "m.mem")


def border_drawn(img: np.ndarray, box: tuple[int, int, int, int]) -> bool:
    """Every pixel on the box's edge is the border colour."""
    x0, y0, x1, y1 = box
    edges = [img[y0, x0:x1], img[y1 - 1, x0:x1], img[y0:y1, x0], img[y0:y1, x1 - 1]]
    return all(bool((e == BORDER).all()) for e in edges)


def blank(img: np.ndarray, box: tuple[int, int, int, int]) -> bool:
    x0, y0, x1, y1 = box
    return bool((img[y0:y1, x0:x1] == BACKGROUND).all())


def drawn_picture(img: np.ndarray, layout: SheetLayout, i: int, thumb: np.ndarray) -> np.ndarray:
    """The pixels where cell i's picture went, below the rank badge, and the thumbnail scaled
    the same way, as int arrays of one shape."""
    fb = fit(layout.thumbs[i], thumb.shape[1], thumb.shape[0])
    want = np.asarray(
        Image.fromarray(thumb).resize((fb[2] - fb[0], fb[3] - fb[1]), Image.Resampling.BILINEAR)
    )
    top = 24  # the badge covers the picture's top-left corner
    return img[fb[1] + top : fb[3], fb[0] : fb[2]].astype(int), want[top:].astype(int)


def test_search_sheet_draws_one_cell_per_hit_with_its_picture(memory: Path, tmp_path: Path) -> None:
    out = tmp_path / "hits.png"
    data = cli_json(
        "search", "--memory", str(memory), "--position", "2.2,1.0", "-k", "5", "--sheet", str(out)
    )
    rows = data["results"]
    assert data["sheet"] == str(out) and len(rows) == 5
    assert [r["id"] for r in rows][:2] == [3, 4]  # nearest first: memory 2 at (2, 1), 3 at (3, 1.5)
    img = read_image(out)
    layout = sheet_layout(len(rows))
    assert img.shape == (layout.height, layout.width, 3)
    assert all(border_drawn(img, box) for box in layout.cells)
    # no sixth cell: where it would go (second row, second column) is blank
    assert blank(img, sheet_layout(8).cells[5])
    thumbs = [read_image(r["image"]) for r in rows]
    for i in range(len(rows)):
        diffs = []
        for t in thumbs:
            got, want = drawn_picture(img, layout, i, t)
            diffs.append(float(np.abs(got - want).mean()))
        assert diffs[i] < 3.0, diffs  # the cell shows its own hit's thumbnail ...
        assert min(d for j, d in enumerate(diffs) if j != i) > 20.0, diffs  # ... and no other


def test_sheet_text_reads_back(memory: Path, tmp_path: Path) -> None:
    """The words under a cell, read back by OCR: rank, id, distance, time, offset and pose."""
    from ravenmem.embed.ocr import OcrReader

    out = tmp_path / "one.png"
    rows = cli_json("search", "--memory", str(memory), "--position", "4,2", "-k", "1", "--sheet", str(out))[
        "results"
    ]
    img = read_image(out)
    layout = sheet_layout(1)
    x0, _, x1, y1 = layout.cells[0]
    text = OcrReader().read(img[layout.thumbs[0][3] : y1, x0:x1]).replace(" ", "")
    r = rows[0]
    assert r["id"] == 5  # memory 4, at (4, 2)
    for part in (
        "#1",
        "id5",
        "0.00maway",
        fmt_time(T0 + 40),
        "(+40.0s)",
        "x4.00",
        "y2.00",
        "z0.10m",
        "yaw46",
    ):
        assert part in text, (part, text)
    title = OcrReader().read(img[layout.title[1] : layout.title[3], :]).replace(" ", "")
    assert "positionsearch:4,2" in title and "1hit(s)" in title, title


def test_empty_search_still_gets_a_sheet(memory: Path, tmp_path: Path) -> None:
    out = tmp_path / "none.png"
    data = cli_json(
        "search", "--memory", str(memory), "--position", "100,100", "--radius", "1", "--sheet", str(out)
    )
    assert data["results"] == []
    img = read_image(out)
    layout = sheet_layout(0)
    assert img.shape == (layout.height, layout.width, 3) and not layout.cells


def test_ask_sheet_shows_the_evidence(memory: Path, tmp_path: Path) -> None:
    out = tmp_path / "ask.png"
    ans = cli_json(
        "ask", "where did I see something blue?", "--memory", str(memory), "--offline", "--sheet", str(out)
    )
    ev = ans["evidence"]
    assert ans["sheet"] == str(out) and ev
    img = read_image(out)
    layout = sheet_layout(len(ev))
    assert img.shape == (layout.height, layout.width, 3)
    assert all(border_drawn(img, box) for box in layout.cells)
    got, want = drawn_picture(img, layout, 0, read_image(ev[0]["image_file"]))
    assert float(np.abs(got - want).mean()) < 3.0


def test_sheet_into_a_folder_that_cannot_be_written(memory: Path, tmp_path: Path) -> None:
    blocker = tmp_path / "file"
    blocker.write_text("x")
    r = cli("search", "--memory", str(memory), "--time", str(T0), "--sheet", str(blocker / "out.png"))
    assert "--sheet: the folder" in assert_one_line_error(r)  # refused before anything is searched


def test_sheets_through_a_running_service_match_local_ones(memory: Path, tmp_path: Path) -> None:
    """With `--server` the pictures come from the service (`/memories/{id}/image`): the cells
    are the same pixels as a sheet drawn from the memory folder."""
    import signal

    pytest.importorskip("fastapi", reason="the serve extra is not installed")
    from tests.server.conftest import serve_subprocess

    proc, url = serve_subprocess(memory, "--read-only")
    try:
        local, remote = tmp_path / "local.png", tmp_path / "remote.png"
        args = ["search", "--position", "3,1", "-k", "6", "--json"]
        rows = cli_json(*args[:-1], "--memory", str(memory), "--sheet", str(local))["results"]
        rows_remote = cli_json(*args[:-1], "--server", url, "--sheet", str(remote))["results"]
        assert [r["id"] for r in rows] == [r["id"] for r in rows_remote]
        a, b = read_image(local), read_image(remote)
        layout = sheet_layout(len(rows))
        assert a.shape == b.shape == (layout.height, layout.width, 3)
        for x0, y0, x1, y1 in layout.cells:
            assert np.array_equal(a[y0:y1, x0:x1], b[y0:y1, x0:x1])
        ask = cli_json(  # over a sheet ravenmem drew: replaced with --force
            "ask",
            "where did I see something green?",
            "--server",
            url,
            "--offline",
            "--sheet",
            str(remote),
            "--force",
        )
        ev = ask["evidence"]
        img = read_image(remote)
        layout = sheet_layout(len(ev))
        with ravenmem.open(memory) as mem:
            thumb = mem.load_image(mem.get([ev[0]["id"]])[0])
        assert thumb is not None
        got, want = drawn_picture(img, layout, 0, thumb)
        assert float(np.abs(got - want).mean()) < 3.0
    finally:
        proc.send_signal(signal.SIGINT)
        proc.wait(60)
