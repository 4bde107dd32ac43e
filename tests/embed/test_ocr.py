"""OCR channel on a rendered sign: the words must come back, in reading order."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from PIL import Image, ImageDraw, ImageFont

from ravenmem.embed.ocr import OcrReader, match_key, normalize_text, ocr_match_score
from ravenmem.errors import InputError


def _font(size: int) -> ImageFont.FreeTypeFont:
    import matplotlib

    path = Path(matplotlib.get_data_path()) / "fonts" / "ttf" / "DejaVuSans-Bold.ttf"
    if not path.exists():
        pytest.skip(f"no TTF font at {path}")
    return ImageFont.truetype(str(path), size)


def _sign(width: int = 640, height: int = 480) -> np.ndarray:
    img = Image.new("RGB", (width, height), (200, 190, 170))
    draw = ImageDraw.Draw(img)
    s = width / 640
    draw.rectangle([int(60 * s), int(50 * s), int(300 * s), int(150 * s)], fill=(20, 120, 40))
    draw.text((int(90 * s), int(60 * s)), "EXIT", font=_font(int(72 * s)), fill=(255, 255, 255))
    draw.text((int(120 * s), int(300 * s)), "ROOM 214", font=_font(int(64 * s)), fill=(10, 10, 10))
    return np.asarray(img)


@pytest.fixture(scope="module")
def reader() -> OcrReader:
    return OcrReader(threads=2)


def test_reads_rendered_words_in_order(reader: OcrReader) -> None:
    text = reader.read(_sign())
    norm = normalize_text(text)
    assert norm.split()[0] == "exit"  # read first: it is above
    assert "214" in norm
    # PP-OCR reads DejaVu's "ROOM 214" as "RO0M214": the match key folds that back
    assert ocr_match_score("room 214", text) == 1.0
    assert ocr_match_score("Exit", text) == 1.0
    assert ocr_match_score("kitchen", text) == 0.0
    words = reader.words(_sign())
    assert all(w.score >= reader.min_score for w in words)
    exit_box = next(w.box for w in words if "EXIT" in w.text.upper())
    xs = [p[0] for p in exit_box]
    assert min(xs) >= 40 and max(xs) <= 330  # box in input pixels, around the green sign


def test_downscaled_large_frame_keeps_words_and_boxes_in_input_pixels() -> None:
    big = _sign(1920, 1440)
    r = OcrReader(max_side=640, threads=2)
    words = r.words(big)
    assert ocr_match_score("room 214", " ".join(w.text for w in words)) == 1.0
    room = next(w for w in words if "214" in w.text)
    assert min(p[1] for p in room.box) > 800  # scaled back to the 1440-px frame


def test_blank_image_reads_nothing(reader: OcrReader) -> None:
    assert reader.read(np.full((240, 320, 3), 255, np.uint8)) == ""


def test_bad_input_is_a_clear_error(reader: OcrReader) -> None:
    with pytest.raises(InputError, match="RGB uint8"):
        reader.read(np.zeros((10, 10), np.uint8))
    with pytest.raises(InputError, match="min_score"):
        OcrReader(min_score=2.0)


def test_normalize_text_and_match_key() -> None:
    assert normalize_text("  Room-214,\nEXIT! ") == "room 214 exit"
    assert match_key("RO0M 214") == match_key("room214")
    assert ocr_match_score("room 215", "ROOM 214") == 0.5  # 'room' read, '215' not
    assert ocr_match_score("a", "a b c") == 0.0  # too short to mean anything
    assert ocr_match_score("exit", "") == 0.0
