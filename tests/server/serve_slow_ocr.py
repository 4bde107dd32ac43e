"""`python tests/server/serve_slow_ocr.py serve --memory DIR ...`: `serve_color.py` with an OCR
that takes a minute per picture, so a test can kill the service while acknowledged frames still
wait for their text (tests/server/test_live_text.py)."""

from __future__ import annotations

import runpy
import time
from pathlib import Path

import ravenmem.embed.ocr as ocr

ocr.OcrReader.read = lambda self, image: (time.sleep(60), "")[1]  # type: ignore[method-assign]

if __name__ == "__main__":
    runpy.run_path(str(Path(__file__).with_name("serve_color.py")), run_name="__main__")
