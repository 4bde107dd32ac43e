"""`ravenmem import`: bulk-add memories whose embeddings were computed elsewhere."""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path
from typing import Annotated

import typer

from .options import COUNT

MemoryOpt = Annotated[Path, typer.Option("--memory", "-m", help="memory folder (created if needed)")]


def import_cmd(
    vectors: Annotated[Path, typer.Argument(help="embeddings: a .npy array (N, dim), row i = memory i")],
    meta: Annotated[
        Path, typer.Option("--meta", help="metadata per row: .parquet, .csv or .jsonl (t, x, y, ...)")
    ],
    memory: MemoryOpt,
    embedder: Annotated[
        str, typer.Option(help="the embedder that computed the vectors (for a new memory)")
    ] = "offline",
    store: Annotated[str | None, typer.Option(help="store URI for a new memory (default: embedded)")] = None,
    chunk: Annotated[int, COUNT, typer.Option(help="memories per transaction")] = 50_000,
    again: Annotated[
        bool, typer.Option("--again", help="import these files again instead of resuming")
    ] = False,
    json_out: Annotated[bool, typer.Option("--json", help="machine-readable output")] = False,
) -> None:
    """Import precomputed embeddings plus metadata (chunked, crash-safe; rerun to resume)."""
    import ravenmem
    from ravenmem.errors import InputError
    from ravenmem.memory.folder import is_memory
    from ravenmem.store.files import import_key, read_batches

    n, dim, batches = read_batches(vectors, meta, chunk)
    if is_memory(memory):
        mem = ravenmem.open(memory)
    else:
        mem = ravenmem.create(memory, embedder=embedder, store=store, thumb_size=0, ocr=False)
    with mem:
        if dim != mem.dim:
            raise InputError(
                f"{vectors} holds {dim}-dim embeddings; memory {memory} ({mem.manifest.embedder}) uses {mem.dim}"
            )
        key = import_key(vectors, meta) + (f"-{time.time_ns()}" if again else "")
        t = time.perf_counter()
        added = mem.import_embeddings(batches, resume=key)
        dt = time.perf_counter() - t
        total = mem.count()
        if added:
            mem.record_ingest(
                {
                    "source": str(vectors),
                    "kind": "import",
                    "frames_seen": added,
                    "kept": added,
                    "skipped": {},
                    "seconds": round(dt, 3),
                }
            )
    out = {
        "memory": str(memory),
        "rows": n,
        "added": added,
        "already_imported": n - added,
        "seconds": round(dt, 3),
        "memories_per_s": round(added / dt, 1) if added and dt > 0 else None,
        "memories_total": total,
    }
    if json_out:
        sys.stdout.write(json.dumps(out, indent=2) + "\n")
        return
    rate = f" ({out['memories_per_s']:,.0f}/s)" if out["memories_per_s"] else ""
    skipped = f"; {n - added} rows were already imported by an earlier run" if n - added else ""
    sys.stdout.write(
        f"imported {added} of {n} memories in {dt:.1f} s{rate}{skipped}; memory now holds {total}\n"
    )


def register(app: typer.Typer) -> None:
    """Add `import` to the main `ravenmem` command."""
    app.command("import")(import_cmd)
