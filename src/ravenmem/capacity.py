"""What this machine can hold: `ravenmem bench`'s measurements and the sizing that follows.

A robot's builder sizes its computer by three questions: how many keyframes per second can the
memory take in (the embedder, and OCR when on), how fast do the four tools answer at the
memory's size, and how many days of memory fit in a GB of disk and of RAM at the robot's
keyframe rate. `measure` answers them in about a minute on the machine it runs on: each
embedder it can load embeds synthetic 640x480 frames for a few seconds (frames/s, ingest's
batch of 16), OCR reads a rendered sign, and the store is either the user's memory (opened
read-only, nothing written) or a synthetic one of 100,000 memories built in a temporary folder;
each tool runs repeatedly (p50/p99 ms). Bytes per memory on disk are the store's (plus
thumbnails for a real memory); in RAM, the growth of the process's resident memory from opening
the store to after its first queries, per memory (Linux; None elsewhere).

Sizing: sustainable keyframes/s is the embedder's frames/s (with OCR: 1 / (1/embed + 1/ocr));
days per GB = 1e9 / (bytes per memory x rate x 86,400) for disk and for RAM, at `rate`
keyframes/s (the paper's robot: 0.12).
"""

from __future__ import annotations

import os
import statistics
import tempfile
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .progress import Eta
from .types import MemoryRecord, Pose

PAPER_RATE = 0.12  # keyframes per second (RAVEN's robot)
SYNTHETIC_N = 100_000
BATCH = 16  # ingest's batch of frames
SECONDS_PER_EMBEDDER = 3.0
QUERIES_PER_TOOL = 30
T0 = 1_700_000_000.0
TOOLS = ("image", "time", "position", "text")
RAM_PROBE = """
import json, sys
import ravenmem
from ravenmem.capacity import _rss_bytes, measure_tools
before = _rss_bytes()
with ravenmem.open(sys.argv[1]) as mem:
    measure_tools(mem, 3, ("image", "time", "position"))
    print(json.dumps({"before": before, "after": _rss_bytes(), "n": mem.count()}))
"""


@dataclass
class EmbedderFigure:
    spec: str  # as asked for (e.g. `offline:runtime=torch`: the name is the same, the runtime not)
    name: str
    frames_per_s: float | None = None
    load_s: float | None = None  # first embed call: graphs, weights, label bank (cached after the first run)
    text_query_ms: float | None = None
    error: str | None = None


@dataclass
class StoreFigure:
    memories: int
    synthetic: bool
    dim: int
    build_s: float | None
    tools: dict[str, dict[str, float]] = field(default_factory=dict)  # tool -> p50_ms, p99_ms
    errors: dict[str, str] = field(default_factory=dict)


@dataclass
class Capacity:
    """Everything `ravenmem bench` prints (and `--json` writes)."""

    machine: dict[str, Any]
    embedders: list[EmbedderFigure]
    ocr_frames_per_s: float | None
    store: StoreFigure
    bytes_per_memory_disk: float
    bytes_per_memory_ram: float | None
    disk_includes_thumbnails: bool
    rate: float
    sizing_embedder: str | None
    keyframes_per_s: float | None
    keyframes_per_s_with_ocr: float | None
    days_per_gb_disk: float | None
    days_per_gb_ram: float | None
    seconds: float

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)


def days_per_gb(bytes_per_memory: float, rate: float) -> float:
    """Days of memory that one GB (1e9 bytes) holds at `rate` keyframes/s."""
    return 1e9 / (bytes_per_memory * rate * 86_400)


def synthetic_frames(n: int, seed: int = 0) -> list[np.ndarray]:
    """640x480 frames with structure (gradients, blocks), so that no embedder sees a blank."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:480, 0:640]
    out = []
    for _ in range(n):
        base = (np.sin(xx / rng.uniform(20, 80)) + np.cos(yy / rng.uniform(20, 80))) * 60 + 128
        img = np.repeat(base[..., None], 3, axis=2) + rng.normal(0, 12, (480, 640, 3))
        x, y = int(rng.integers(0, 480)), int(rng.integers(0, 320))
        img[y : y + 160, x : x + 160] = rng.uniform(0, 255, 3)
        out.append(np.clip(img, 0, 255).astype(np.uint8))
    return out


def measure_embedder(spec: Any, seconds: float = SECONDS_PER_EMBEDDER) -> EmbedderFigure:
    """frames/s of `embed_images` in batches of 16 for about `seconds` (at least one batch)."""
    from .embed import create_embedder

    label = spec if isinstance(spec, str) else getattr(spec, "name", str(spec))
    name = label
    try:
        emb = create_embedder(spec) if isinstance(spec, str) else spec
        name = emb.name
        frames = synthetic_frames(BATCH)
        t0 = time.perf_counter()
        emb.embed_images(frames[:1])
        emb.embed_texts(["warm-up"])
        load = time.perf_counter() - t0
        texts = []
        for q in ("a red mug on a desk", "a door", "the kitchen"):
            t0 = time.perf_counter()
            emb.embed_texts([q])
            texts.append((time.perf_counter() - t0) * 1000)
        done, t0 = 0, time.perf_counter()
        while True:
            emb.embed_images(frames)
            done += len(frames)
            if time.perf_counter() - t0 >= seconds:
                break
        return EmbedderFigure(label, name, done / (time.perf_counter() - t0), load, statistics.median(texts))
    except Exception as e:  # any backend failure is reported, not fatal: the others still count
        return EmbedderFigure(label, name, error=f"{type(e).__name__}: {e}"[:200])


def measure_ocr(seconds: float = 2.0) -> float | None:
    """frames/s of the OCR reader on a 640x480 frame with a sign on it; None without OCR."""
    try:
        from PIL import Image, ImageDraw

        from .embed.ocr import OcrReader

        img = Image.fromarray(synthetic_frames(1, seed=1)[0])
        draw = ImageDraw.Draw(img)
        draw.rectangle((200, 180, 440, 260), fill=(255, 255, 255))
        draw.text((220, 200), "ROOM 214", fill=(0, 0, 0), font_size=36)
        frame = np.asarray(img)
        reader = OcrReader()
        reader.read(frame)  # load the models outside the timing
        done, t0 = 0, time.perf_counter()
        while True:
            reader.read(frame)
            done += 1
            if time.perf_counter() - t0 >= seconds:
                break
        return done / (time.perf_counter() - t0)
    except Exception:  # OCR is optional: the sizing then leaves it out
        return None


def _rss_bytes() -> int | None:
    try:
        with open("/proc/self/statm", encoding="ascii") as f:
            return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")
    except (OSError, ValueError, IndexError, AttributeError):
        return None


def _synthetic_batches(
    n: int, dim: int, batch: int = 20_000
) -> Iterator[tuple[list[MemoryRecord], np.ndarray]]:
    """A robot's day in vectors: visits to places (a look in embedding space and a spot on the
    map), frames drifting within a visit, one keyframe every 2 s."""
    rng = np.random.default_rng(0)
    places = max(4, n // 400)
    looks = rng.normal(size=(places, dim)).astype(np.float32)
    spots = rng.uniform(5, 95, (places, 2))
    for start in range(0, n, batch):
        m = min(batch, n - start)
        place = np.repeat(rng.integers(0, places, m // 200 + 1), 200)[:m]
        emb = looks[place] + rng.normal(0, 0.5, (m, dim)).astype(np.float32)
        emb /= np.linalg.norm(emb, axis=1, keepdims=True)
        pos = spots[place] + rng.normal(0, 1.0, (m, 2))
        yaw = rng.uniform(-3, 3, m)
        recs = [
            MemoryRecord(
                id=-1,
                t=T0 + 2.0 * (start + i),
                pose=Pose(float(pos[i, 0]), float(pos[i, 1]), 0.0, float(yaw[i])),
                source="bench",
                frame_index=start + i,
            )
            for i in range(m)
        ]
        yield recs, emb


def _counted(
    batches: Iterator[tuple[list[MemoryRecord], np.ndarray]], eta: Eta
) -> Iterator[tuple[list[MemoryRecord], np.ndarray]]:
    """The batches as they are, with a progress line as each one is taken."""
    done = 0
    eta.update(0, force=True)
    for recs, emb in batches:
        yield recs, emb
        done += len(recs)
        eta.update(done)


def _percentiles(fn: Callable[[int], object], n: int) -> dict[str, float]:
    fn(0)  # warm
    times = []
    for i in range(n):
        t0 = time.perf_counter()
        fn(i)
        times.append((time.perf_counter() - t0) * 1000)
    times.sort()
    return {"p50_ms": statistics.median(times), "p99_ms": times[min(len(times) - 1, int(0.99 * len(times)))]}


def measure_tools(
    mem: Any, queries: int = QUERIES_PER_TOOL, tools: tuple[str, ...] = TOOLS
) -> tuple[dict[str, dict[str, float]], dict[str, str]]:
    """p50/p99 ms of each tool as `Memory` runs it (text includes embedding the query)."""
    t_min, t_max = mem.time_span()
    ids = [h.memory.id for h in mem.search_time(t_min, k=min(queries, 100))] or [1]
    extent = mem.info().get("extent") or {"x": [0.0, 1.0], "y": [0.0, 1.0]}
    (x0, x1), (y0, y1) = extent["x"], extent["y"]
    xs, ys = np.linspace(float(x0), float(x1), queries), np.linspace(float(y0), float(y1), queries)
    words = ["a red mug", "a door", "a computer keyboard", "a person", "an office chair", "a window"]
    calls: dict[str, Callable[[int], object]] = {
        "text": lambda i: mem.search_text(words[i % len(words)], k=5),
        "image": lambda i: mem.search_image(memory_id=ids[i % len(ids)], k=5),
        "time": lambda i: mem.search_time(t_min + (t_max - t_min) * (i % queries) / queries, k=5),
        "position": lambda i: mem.search_position(float(xs[i % queries]), float(ys[i % queries]), k=5),
    }
    out, errors = {}, {}
    for tool in tools:
        try:
            out[tool] = _percentiles(calls[tool], queries)
        except Exception as e:  # e.g. the memory's embedder cannot load here: the other tools still count
            errors[tool] = f"{type(e).__name__}: {e}"[:200]
    return out, errors


def measure(
    memory: str | os.PathLike[str] | None = None,
    rate: float = PAPER_RATE,
    synthetic_n: int = SYNTHETIC_N,
    embedder_seconds: float = SECONDS_PER_EMBEDDER,
    say: Callable[[str], None] | None = None,
    embedders: Sequence[str] | None = None,
) -> Capacity:
    """Run every measurement (see the module docstring). `memory` is opened read-only. `say`
    gets a line as each step starts and ends (a minute of silence reads as a hang).
    `embedders`: the specs to measure after the memory's own embedder (default: `offline`, and
    `offline:runtime=torch` where torch is installed)."""
    import ravenmem

    from .embed.base import default_threads

    say = say or (lambda line: None)
    start = time.perf_counter()
    specs: list[str] = []
    mem_path = Path(memory) if memory is not None else None
    if mem_path is not None:
        with ravenmem.open(mem_path) as m:
            specs.append(m.manifest.embedder)
    specs += [
        s for s in dict.fromkeys(default_specs(specs) if embedders is None else embedders) if s not in specs
    ]
    figures = []
    for i, spec in enumerate(specs, 1):
        say(f"[{i}/{len(specs) + 3}] embedder {spec}: loading, then embedding for {embedder_seconds:g} s")
        figures.append(measure_embedder(spec, embedder_seconds))
        e = figures[-1]
        say(f"  {e.error or f'{e.frames_per_s:.1f} frames/s'}")
    say(f"[{len(specs) + 1}/{len(specs) + 3}] OCR: reading a rendered sign for 2 s")
    ocr = measure_ocr()
    say(f"  {f'{ocr:.1f} frames/s' if ocr else 'unavailable'}")

    with tempfile.TemporaryDirectory(prefix="ravenmem-bench-") as tmp:
        build_s = None
        if mem_path is None:
            dim = 384
            path = Path(tmp) / "synthetic.mem"
            t0 = time.perf_counter()
            step = f"[{len(specs) + 2}/{len(specs) + 3}] store: building a synthetic one"
            eta = Eta(say, step, synthetic_n)
            with ravenmem.create(path, embedder="offline", ocr=False, thumb_size=0) as m:
                dim = m.dim
                m.import_embeddings(_counted(_synthetic_batches(synthetic_n, dim), eta))
            build_s = time.perf_counter() - t0
        else:
            path = mem_path
        say(
            f"[{len(specs) + 3}/{len(specs) + 3}] store: RAM per memory, then each tool {QUERIES_PER_TOOL} times"
        )
        ram = _ram_per_memory(path)
        with ravenmem.open(path) as mem:
            info = mem.info()
            tools, errors = measure_tools(mem)
            n = int(info["memories"])
            store = StoreFigure(n, mem_path is None, int(info["dim"]), build_s, tools, errors)
    with_thumbs = mem_path is not None and bool(info.get("thumb_bytes"))
    disk = float(info["bytes_per_memory_with_thumbs"] if with_thumbs else info["bytes_per_memory"] or 0.0)
    sizing = next((e for e in figures if e.frames_per_s), None)
    kf = sizing.frames_per_s if sizing else None
    kf_ocr = 1.0 / (1.0 / kf + 1.0 / ocr) if kf and ocr else None
    return Capacity(
        machine=_machine(default_threads()),
        embedders=figures,
        ocr_frames_per_s=ocr,
        store=store,
        bytes_per_memory_disk=disk,
        bytes_per_memory_ram=ram,
        disk_includes_thumbnails=with_thumbs,
        rate=rate,
        sizing_embedder=sizing.name if sizing else None,
        keyframes_per_s=kf,
        keyframes_per_s_with_ocr=kf_ocr,
        days_per_gb_disk=days_per_gb(disk, rate) if disk else None,
        days_per_gb_ram=days_per_gb(ram, rate) if ram else None,
        seconds=time.perf_counter() - start,
    )


def default_specs(first: list[str]) -> list[str]:
    """What `ravenmem bench` measures after `first` (the memory's embedder) unless told: the
    offline embedder (unless the memory's is one), and its torch runtime where torch is installed."""
    import importlib.util

    out = [] if any(s == "offline" or s.startswith("offline:") for s in first) else ["offline"]
    if importlib.util.find_spec("torch") is not None:
        out.append("offline:runtime=torch")
    return out


def _ram_per_memory(path: Path) -> float | None:
    """Resident memory the open store takes per memory, measured in a fresh process (this one's
    heap has been through building and embedding): RSS after opening it and running the image,
    time and position tools, minus RSS before opening, over the memory count."""
    import json
    import subprocess
    import sys

    try:
        r = subprocess.run(
            [sys.executable, "-c", RAM_PROBE, str(path)], capture_output=True, text=True, timeout=300
        )
        doc = json.loads(r.stdout.strip().splitlines()[-1])
    except (OSError, subprocess.SubprocessError, ValueError, IndexError):
        return None
    if doc.get("before") is None or doc.get("after") is None or not doc.get("n"):
        return None
    per = (doc["after"] - doc["before"]) / doc["n"]
    return per if per > 0 else None


def _machine(threads: int) -> dict[str, Any]:
    """CPU count, the embedder's thread default and what accelerators onnxruntime can use."""
    try:
        import onnxruntime as ort

        # the CPU provider and the Azure one (a remote-call provider, not a device) are no accelerators
        providers = [
            p
            for p in ort.get_available_providers()
            if p not in ("CPUExecutionProvider", "AzureExecutionProvider")
        ]
    except ImportError:
        providers = []
    gpu = ", ".join(providers) if providers else "none (no GPU provider in onnxruntime here: CPU only)"
    return {"cpus": os.cpu_count(), "embedder_threads": threads, "accelerators": gpu}
