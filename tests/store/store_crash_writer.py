"""Child process for the crash test: adds batches forever, printing each acknowledged batch.

Usage: python store_crash_writer.py URI DIM BATCH OPTIONS_JSON. The parent kills it with
SIGKILL at some point; every batch printed before that must be in the store on reopen.
"""

from __future__ import annotations

import json
import sys

from ravenmem.store import open_store
from tests.store.store_helpers import batch_data


def main() -> None:
    uri, dim, batch, options = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), json.loads(sys.argv[4])
    store = open_store(uri, dim, **options)
    b = 0
    while True:
        recs, emb = batch_data(b, batch, dim)
        ids = store.add(recs, emb)
        print(b, ids[0], ids[-1], flush=True)
        b += 1


if __name__ == "__main__":
    main()
