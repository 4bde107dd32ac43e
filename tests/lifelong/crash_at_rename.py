"""Child process: the real `ravenmem` command, killed (SIGKILL) just before the atomic rename
of a file whose name starts with PREFIX.

Usage: python crash_at_rename.py PREFIX ARGS...  (ARGS as for `ravenmem`). The file's
temporary copy is written, fsynced and no longer locked when the process dies: a moment a
kill -9 only hits by chance in the random tests (a few milliseconds of a run).
"""

from __future__ import annotations

import os
import signal
import sys

from ravenmem.cli import main as cli


def main() -> None:
    prefix = sys.argv[1]
    real_replace = os.replace

    def replace(src, dst, *args, **kwargs):  # type: ignore[no-untyped-def]
        if os.path.basename(os.fspath(dst)).startswith(prefix):
            os.kill(os.getpid(), signal.SIGKILL)
        return real_replace(src, dst, *args, **kwargs)

    os.replace = replace  # type: ignore[assignment]
    sys.argv = ["ravenmem", *sys.argv[2:]]
    cli.main()


if __name__ == "__main__":
    main()
