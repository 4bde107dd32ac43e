"""Child process: the real `ravenmem` command, killed (SIGKILL) inside the store's N-th add.

Usage: python crash_ingest.py N ARGS...  (ARGS as for `ravenmem`). The N-th batch's thumbnails
are on disk and its records not yet committed when the process dies: the moment a kill -9 can
only hit by chance in the random test.
"""

from __future__ import annotations

import os
import signal
import sys

from ravenmem.cli import main as cli
from ravenmem.store.local import LocalStore


def main() -> None:
    n = int(sys.argv[1])
    calls = 0
    real_add = LocalStore.add

    def add(self, records, embeddings):  # type: ignore[no-untyped-def]
        nonlocal calls
        calls += 1
        if calls == n:
            os.kill(os.getpid(), signal.SIGKILL)
        return real_add(self, records, embeddings)

    LocalStore.add = add  # type: ignore[method-assign]
    sys.argv = ["ravenmem", *sys.argv[2:]]
    cli.main()


if __name__ == "__main__":
    main()
