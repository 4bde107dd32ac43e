"""Child process for the crash tests, killed with SIGKILL by the parent at some point.

Usage: python store_crash_writer.py URI DIM BATCH OPTIONS_JSON [MODE]
- add (default): adds batches forever, printing each acknowledged batch (b, first id, last id);
- delete: fills an empty store with 40 batches, then deletes the memories of batch b = 0, 1, ...
  (ids b*BATCH+1 .. (b+1)*BATCH) one call each, printing b after each call returned;
- import: `add_many` with resume name "crash" over an endless stream of batches, printing b when
  batch b+1 is asked for (batch b is then committed).
"""

from __future__ import annotations

import json
import sys
from collections.abc import Iterator

import numpy as np

from ravenmem.store import open_store
from tests.store.store_helpers import batch_data


def main() -> None:
    uri, dim, batch, options = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), json.loads(sys.argv[4])
    mode = sys.argv[5] if len(sys.argv) > 5 else "add"
    store = open_store(uri, dim, **options)
    if mode == "delete" and store.count() == 0:
        for i in range(40):
            store.add(*batch_data(i, batch, dim))
    print("ready", flush=True)
    b = 0
    if mode == "add":
        while True:
            recs, emb = batch_data(b, batch, dim)
            ids = store.add(recs, emb)
            print(b, ids[0], ids[-1], flush=True)
            b += 1
    elif mode == "delete":
        while True:
            store.delete(np.arange(b * batch + 1, (b + 1) * batch + 1))  # type: ignore[attr-defined]
            print(b, flush=True)
            b += 1
    else:

        def batches() -> Iterator[tuple[list, np.ndarray]]:
            for i in range(10**6):
                if i:
                    print(i - 1, flush=True)
                yield batch_data(i, batch, dim)

        store.add_many(batches(), resume="crash")  # type: ignore[attr-defined]


if __name__ == "__main__":
    main()
