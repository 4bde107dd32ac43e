"""`ravenmem bench`: what this machine can hold (ravenmem.capacity), in about a minute."""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Annotated

import typer

from ..errors import InputError
from .options import MEASURE, RATE, SYNTHETIC


def bench_cmd(
    memory: Annotated[
        Path | None,
        typer.Option(
            "--memory",
            "-m",
            help="measure the store at this memory's size (read-only); default: a synthetic 100k",
        ),
    ] = None,
    rate: Annotated[
        float, RATE, typer.Option(help="the robot's keyframes per second (the paper's: 0.12)")
    ] = 0.12,
    synthetic: Annotated[
        int, SYNTHETIC, typer.Option(help="memories in the synthetic store (without --memory)")
    ] = 100_000,
    seconds: Annotated[float, MEASURE, typer.Option(help="seconds of embedding per embedder")] = 3.0,
    embedder: Annotated[
        list[str] | None,
        typer.Option(
            "--embedder",
            help="an embedder to measure (repeatable; after the memory's own); default: offline, "
            "and offline:runtime=torch where torch is installed",
        ),
    ] = None,
    json_out: Annotated[bool, typer.Option("--json", help="machine-readable output")] = False,
) -> None:
    """Measure the embedders, OCR and the store here; print keyframes/s and days of memory per GB."""
    from ravenmem.capacity import measure

    if memory is not None and not (memory / "memory.json").is_file():
        raise InputError(f"{memory}: not a ravenmem memory (no memory.json)")

    def say(line: str) -> None:  # progress as it goes, on stderr (stdout keeps the results)
        print(line, file=sys.stderr, flush=True)

    cap = measure(
        memory, rate=rate, synthetic_n=synthetic, embedder_seconds=seconds, say=say, embedders=embedder
    )
    if json_out:
        print(json.dumps(cap.as_dict(), indent=2))
        return
    m = cap.machine
    print(
        f"machine: {m['cpus']} CPUs, embedder threads {m['embedder_threads']}; accelerators: {m['accelerators']}"
    )
    print("embedders (frames/s at ingest's batch of 16, 640x480 frames):")
    for e in cap.embedders:
        label = e.name if e.spec in ("offline", e.name) else f"{e.spec} ({e.name})"
        if e.error:
            print(f"  {label}: unavailable ({e.error})")
        else:
            print(
                f"  {label}: {e.frames_per_s:.1f} frames/s, text query {e.text_query_ms:.0f} ms "
                f"(first use {e.load_s:.1f} s)"
            )
    print(f"OCR: {f'{cap.ocr_frames_per_s:.1f} frames/s' if cap.ocr_frames_per_s else 'unavailable'}")
    st = cap.store
    what = "synthetic" if st.synthetic else "this memory"
    built = f", built in {st.build_s:.1f} s" if st.build_s is not None else ""
    print(f"store: {st.memories:,} memories ({what}, dim {st.dim}{built}):")
    for tool, t in st.tools.items():
        print(f"  {tool:<9} p50 {t['p50_ms']:.2f} ms, p99 {t['p99_ms']:.2f} ms")
    for tool, err in st.errors.items():
        print(f"  {tool:<9} failed ({err})")
    thumbs = "with thumbnails" if cap.disk_includes_thumbnails else "store only, no thumbnails"
    ram = f"{cap.bytes_per_memory_ram:,.0f} B" if cap.bytes_per_memory_ram else "unknown"
    print(f"bytes per memory: disk {cap.bytes_per_memory_disk:,.0f} B ({thumbs}), RAM {ram}")
    if cap.keyframes_per_s:
        ocr = f", {cap.keyframes_per_s_with_ocr:.1f} with OCR" if cap.keyframes_per_s_with_ocr else ""
        print(
            f"sustainable: {cap.keyframes_per_s:.1f} keyframes/s{ocr} ({cap.sizing_embedder}); "
            f"{cap.keyframes_per_s / cap.rate:,.0f}x the rate of {cap.rate:g} keyframes/s"
        )
    else:
        print("sustainable: unknown (no embedder could run here)")
    disk_days = f"{cap.days_per_gb_disk:,.1f}" if cap.days_per_gb_disk else "unknown"
    ram_days = f"{cap.days_per_gb_ram:,.1f}" if cap.days_per_gb_ram else "unknown"
    print(f"at {cap.rate:g} keyframes/s: {disk_days} days of memory per GB of disk, {ram_days} per GB of RAM")
    print(f"measured in {cap.seconds:.0f} s")


def register(app: typer.Typer) -> None:
    app.command("bench")(bench_cmd)
