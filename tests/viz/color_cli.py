"""`python tests/viz/color_cli.py ARGS`: the real `ravenmem` command with the colour test embedder
registered by name, so subprocess tests that search by text start in a second instead of
loading the offline models."""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from ravenmem.cli.main import main  # noqa: E402
from ravenmem.embed.base import EMBEDDERS  # noqa: E402
from tests.conftest import ColorEmbedder  # noqa: E402

EMBEDDERS.register("test-color")(lambda spec, **kw: ColorEmbedder())

if __name__ == "__main__":
    sys.argv = ["ravenmem", *sys.argv[1:]]
    main()
