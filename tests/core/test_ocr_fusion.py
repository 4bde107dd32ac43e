"""The text tool finds a sign by the words in it even when the image embedder cannot read."""

from __future__ import annotations

from pathlib import Path

import matplotlib
import numpy as np
from PIL import Image, ImageDraw, ImageFont

import ravenmem
from ravenmem.types import Frame, Pose
from tests.conftest import solid

FONT = Path(matplotlib.get_data_path()) / "fonts" / "ttf" / "DejaVuSans-Bold.ttf"


def sign(text: str, color: str) -> np.ndarray:
    img = Image.fromarray(solid(color, 240, 480))
    draw = ImageDraw.Draw(img)
    draw.rectangle((20, 70, 460, 170), fill=(255, 255, 255))
    draw.text((40, 88), text, fill=(0, 0, 0), font=ImageFont.truetype(str(FONT), 52))
    return np.asarray(img)


def test_ocr_channel_fused_into_text_search(tmp_path, color_embedder):
    mem = ravenmem.create(tmp_path / "s.mem", embedder=color_embedder, ocr=True, thumb_size=0)
    texts = ["ROOM 214", "EXIT", "ROOM 305"]
    frames = [
        Frame(image=sign(t, "blue"), t=100.0 + i, pose=Pose(float(i), 0.0), index=i)
        for i, t in enumerate(texts)
    ]
    frames.append(Frame(image=solid("blue", 240, 480), t=110.0, pose=Pose(9.0, 0.0), index=9))
    mem.add_frames(frames)
    recs = mem.all_records()
    assert "214" in recs[0].ocr_text and "exit" in recs[1].ocr_text.lower()
    # all four images are equally "blue" to the colour embedder: only the OCR channel can tell them apart
    hits = mem.search_text("the room number 214", k=2)
    assert hits[0].memory.frame_index == 0 and hits[0].ocr_match and not hits[1].ocr_match
    hits = mem.search_text("where is the EXIT sign", k=4)
    assert hits[0].memory.frame_index == 1 and hits[0].ocr_match
    plain = next(h for h in hits if h.memory.frame_index == 9)  # same colour, no text: cosine only
    assert hits[0].score > plain.score + 0.1 and not plain.ocr_match
    mem.close()
