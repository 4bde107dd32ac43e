"""Write docs/cli.md, the command reference, from the `ravenmem` command tree
(`ravenmem.cli.reference`); `--check` only says whether the committed page is current
(exit 1 when it is not: the test suite runs this).

    python scripts/gen_cli_docs.py            # (re)write docs/cli.md
    python scripts/gen_cli_docs.py --check    # exit 1 when docs/cli.md is out of date
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
PAGE = REPO / "docs" / "cli.md"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true", help="exit 1 when the page is out of date")
    parser.add_argument("--page", type=Path, default=PAGE, help="the page (default: docs/cli.md)")
    args = parser.parse_args(argv)
    from ravenmem.cli.main import app
    from ravenmem.cli.reference import render

    page = render(app)
    current = args.page.read_text(encoding="utf-8") if args.page.is_file() else None
    if args.check:
        if current != page:
            print(f"{args.page} is out of date: run python scripts/gen_cli_docs.py", file=sys.stderr)
            return 1
        return 0
    if current != page:
        args.page.write_text(page, encoding="utf-8")
        print(f"wrote {args.page}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
