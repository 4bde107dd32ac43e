"""Console helpers shared by the command modules."""

from __future__ import annotations

import sys

from rich.console import Console


def out_console() -> Console:
    """Terminal width on a terminal; wide enough for tables when piped (rich would use 80)."""
    return Console() if sys.stdout.isatty() else Console(width=200)
