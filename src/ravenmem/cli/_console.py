"""Console helpers shared by the command modules.

Rich reads `[...]` in printed strings as markup: a time typed as `[/bold] x` crashes the print
(MarkupError) and a message holding `[nan, nan, 1.0]` loses that part silently. So every piece
of user, model or error text goes through `esc` before it is printed with markup, and error
lines are printed as plain `Text`, never parsed.
"""

from __future__ import annotations

import sys
from typing import Any

from rich.console import Console
from rich.markup import escape
from rich.text import Text


def out_console() -> Console:
    """Terminal width on a terminal; wide enough for tables when piped (rich would use 80)."""
    return Console() if sys.stdout.isatty() else Console(width=200)


def esc(value: object) -> str:
    """`value` as text that rich prints literally (brackets escaped)."""
    return escape(str(value))


def one_line(message: object) -> str:
    """A message on one line (errors from libraries sometimes span several)."""
    return " ".join(part.strip() for part in str(message).splitlines() if part.strip())


def print_error(message: object) -> None:
    """`error: <message>` on stderr, on one line, never parsed as markup and never wrapped."""
    err = Console(stderr=True, soft_wrap=True, highlight=False)
    err.print(Text.assemble(("error:", "red"), " ", one_line(message)))


def print_warning(message: object) -> None:
    """`warning: <message>` on stderr, like `print_error` (something the user must hear about
    while the command still succeeds, e.g. a video that ended early)."""
    err = Console(stderr=True, soft_wrap=True, highlight=False)
    err.print(Text.assemble(("warning:", "yellow"), " ", one_line(message)))


def rounded(data: Any, places: int = 4) -> Any:
    """JSON for a person: floats to `places` decimals (a tenth of a millimetre on the map), the
    rest as is. The goal lines of `navigate` and `ask --navigate` print through it; `--json`
    keeps every digit."""
    if isinstance(data, float):
        return round(data, places)
    if isinstance(data, dict):
        return {k: rounded(v, places) for k, v in data.items()}
    if isinstance(data, list):
        return [rounded(v, places) for v in data]
    return data
