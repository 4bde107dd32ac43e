"""The OCR channel: words visible in a frame ("EXIT", "ROOM 214"), stored with each memory.

Embedders are poor at reading; a robot asked for "room 214" is better served by matching the
words it read. `OcrReader` wraps RapidOCR (PP-OCR models run by onnxruntime, shipped inside the
`rapidocr-onnxruntime` wheel, so nothing is downloaded). The models load on first use.
"""

from __future__ import annotations

import re
import threading
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..errors import InputError

OCR_WEIGHT = 0.35
"""Fused text score = cosine + OCR_WEIGHT * ocr_score (ocr_score in [0, 1]): a full match of the
words a frame shows outweighs the cosine gap between a right and a wrong frame."""

STOPWORDS = frozenset(
    [
        "the",
        "a",
        "an",
        "of",
        "to",
        "in",
        "on",
        "at",
        "for",
        "with",
        "by",
        "and",
        "or",
        "my",
        "our",
        "your",
        "this",
        "that",
        "is",
        "are",
        "was",
        "were",
        "some",
        "any",
    ]
)
"""Function words that never have to be read in a frame."""

QUERY_FILLER = frozenset(
    [
        "from",
        "be",
        "been",
        "where",
        "when",
        "what",
        "which",
        "who",
        "how",
        "did",
        "do",
        "does",
        "i",
        "me",
        "we",
        "you",
        "it",
        "its",
        "these",
        "those",
        "there",
        "here",
        "last",
        "first",
        "seen",
        "see",
        "saw",
        "find",
        "show",
        "sign",
        "number",
        "room",
        "label",
        "text",
        "written",
        "says",
        "say",
    ]
)
"""Words of a question about text that are not the text itself ("the sign that says EXIT")."""


def ocr_terms(query: str) -> str:
    """The words of a query worth looking for in OCR text (stopwords and filler dropped)."""
    words = [w.strip(".,;:!?\"'()[]") for w in query.split()]
    keep = [w for w in words if len(w) >= 2 and w.lower() not in STOPWORDS | QUERY_FILLER] or words
    return " ".join(keep)


@dataclass(frozen=True)
class OcrWord:
    """One recognised text line with its confidence and its box (4 (x, y) corners, input pixels)."""

    text: str
    score: float
    box: tuple[tuple[float, float], ...]


class OcrReader:
    """Read the text in RGB frames.

    `min_score` drops low-confidence lines (RapidOCR's own cut is 0.5). `max_side` downscales
    frames whose longer side exceeds it before detection: OCR time grows with pixels and signs
    that matter to a robot are large. `det_side` is the detector's input size (RapidOCR upscales
    a 640x480 frame to 736 px on the short side by default, which triples the work for no gain on
    large text). `threads` caps onnxruntime's threads (None: onnxruntime decides). Lines with
    fewer than `min_chars` letters/digits are dropped: on cluttered desks the recogniser turns
    texture into single characters, and a one-letter "word" is useless for search anyway.
    """

    def __init__(
        self,
        min_score: float = 0.6,
        max_side: int | None = 1280,
        det_side: int | None = 480,
        use_angle_cls: bool = False,
        threads: int | None = None,
        min_chars: int = 2,
    ) -> None:
        if not 0.0 <= min_score <= 1.0:
            raise InputError(f"OcrReader: min_score={min_score} must be in [0, 1]")
        if max_side is not None and max_side < 32:
            raise InputError(f"OcrReader: max_side={max_side} must be >= 32")
        self.min_score = min_score
        self.max_side = max_side
        self.det_side = det_side
        self.use_angle_cls = use_angle_cls
        self.threads = threads
        self.min_chars = min_chars
        self._engine: Any = None
        self._lock = threading.Lock()

    def _load(self) -> Any:
        with self._lock:
            if self._engine is None:
                from rapidocr_onnxruntime import RapidOCR

                kwargs: dict[str, Any] = {"text_score": self.min_score, "use_cls": self.use_angle_cls}
                if self.det_side is not None:
                    kwargs.update(det_limit_side_len=self.det_side, det_limit_type="min")
                if self.threads is not None:
                    kwargs.update(intra_op_num_threads=self.threads, inter_op_num_threads=1)
                self._engine = RapidOCR(**kwargs)
            return self._engine

    def words(self, image: np.ndarray) -> list[OcrWord]:
        """Recognised text lines, top-to-bottom then left-to-right, with scores >= min_score."""
        arr = np.asarray(image)
        if arr.ndim != 3 or arr.shape[2] != 3 or arr.dtype != np.uint8:
            raise InputError(f"OCR: expected an RGB uint8 array (H, W, 3), got {arr.dtype} {arr.shape}")
        scale = 1.0
        if self.max_side is not None and max(arr.shape[:2]) > self.max_side:
            from PIL import Image

            scale = self.max_side / max(arr.shape[:2])
            size = (max(1, round(arr.shape[1] * scale)), max(1, round(arr.shape[0] * scale)))
            arr = np.asarray(Image.fromarray(arr).resize(size, Image.Resampling.BILINEAR))
        bgr = np.ascontiguousarray(arr[:, :, ::-1])  # RapidOCR treats 3-channel arrays as BGR
        result, _ = self._load()(bgr, use_cls=self.use_angle_cls)
        out = []
        for box, text, score in result or []:
            if float(score) < self.min_score or sum(ch.isalnum() for ch in str(text)) < self.min_chars:
                continue
            pts = tuple((float(x) / scale, float(y) / scale) for x, y in box)
            out.append(OcrWord(str(text).strip(), float(score), pts))
        out.sort(key=lambda w: (round(min(p[1] for p in w.box) / 10), min(p[0] for p in w.box)))
        return out

    def read(self, image: np.ndarray) -> str:
        """All recognised text of a frame joined by spaces ('' when none)."""
        return " ".join(w.text for w in self.words(image))


def normalize_text(text: str) -> str:
    """Lower-case, punctuation to spaces, single spaces: a readable normalised copy."""
    return " ".join(re.sub(r"[^\w]+", " ", text.lower()).split())


# characters OCR confuses on signs ("RO0M", "F1LE", "5TOP"); folded alike on both sides of a match
_FOLD = str.maketrans({"0": "o", "1": "l", "i": "l", "|": "l", "5": "s"})


def match_key(text: str) -> str:
    """Lower-case, letters and digits only (OCR often drops spaces), confusable characters folded."""
    return "".join(ch for ch in text.lower() if ch.isalnum()).translate(_FOLD)


def ocr_match_score(query: str, ocr_text: str) -> float:
    """How much of `query` was read in `ocr_text`: 1.0 when the whole query appears (ignoring
    spaces, case and O/0-style confusions), else the fraction of its words (>= 2 characters) that
    appear; 0.0 when nothing does. Used to fuse the OCR channel with embedding similarity."""
    hay = match_key(ocr_text)
    whole = match_key(query)
    if not hay or len(whole) < 2:
        return 0.0
    if whole in hay:
        return 1.0
    words = [k for k in (match_key(w) for w in query.split()) if len(k) >= 2]
    return sum(k in hay for k in words) / len(words) if words else 0.0
