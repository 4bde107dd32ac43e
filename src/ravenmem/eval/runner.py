"""The evaluation runner: dataset x methods x seeds -> one JSONL row per answer, resumable.

A run folder (`runs/<date>/<name>/` by default) holds `config.json`, `answers.jsonl` (one row
per question x method x seed, appended and flushed as each answer arrives) and `summary.json`.
Running the same command again skips rows already present, so a crashed or interrupted run
resumes where it stopped; a different configuration in the same folder is refused. Questions
run in parallel on a bounded thread pool; each worker borrows its own method instance (the
agent keeps per-question cost counters), except `random`, built per question from a seed derived
from (seed, question id) so its answers do not depend on scheduling.
"""

from __future__ import annotations

import hashlib
import json
import os
import queue
import re
import sys
import threading
import time
from collections.abc import Callable, Iterator
from concurrent.futures import ThreadPoolExecutor, as_completed
from contextlib import contextmanager
from dataclasses import asdict, dataclass, field
from datetime import datetime, timezone
from fnmatch import fnmatch
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from ..agent.schema import Answer
from ..errors import InputError
from ..fsio import atomic_open, atomic_write, atomic_write_json
from ..imageio import read_image
from ..ingest.keyframes import KeyframeConfig, parse_keyframes
from .cache import CachingEmbedder, build_memory
from .datasets import load_dataset
from .metrics import Thresholds, prediction, score_row, summarize, truth_row
from .types import Episode, Question, horizon_of

VLM_METHODS = ("raven", "vlm-only", "caption")
METHOD_NAMES = ("raven", "offline", "embedder-only", "vlm-only", "caption", "random")
# Settings that change answers: a run folder holds one value of each (methods and seeds may grow).
IDENTITY = ("dataset", "queries", "embedder", "vlm", "vlm_base_url", "keyframes", "ocr", "thumb_size", "method_opts",
            "dataset_opts")  # fmt: skip


@dataclass
class RunConfig:
    dataset: str
    methods: list[str]
    queries: str | None = None
    embedder: str = "offline"
    vlm: str | None = None
    vlm_base_url: str | None = None
    seeds: int = 1
    out: str | None = None
    runs_dir: str = "runs"
    name: str | None = None
    cache_dir: str = ".ravenmem-cache/eval"
    workers: int = 4
    keyframes: str | None = None
    ocr: bool = False
    thumb_size: int = 320
    method_opts: dict[str, Any] = field(default_factory=dict)
    dataset_opts: dict[str, Any] = field(default_factory=dict)
    thresholds: dict[str, Any] = field(default_factory=dict)
    judge_model: str | None = None
    judge_base_url: str | None = None
    limit: int | None = None
    episodes: str | None = None  # glob over episode ids
    retry_failed: bool = False
    progress: bool | None = None
    variant: str = ""  # a label that separates rows of otherwise equal settings in reports (studies)

    def validate(self, known: tuple[str, ...] | None = METHOD_NAMES) -> None:
        """Check options; `known` = the method names allowed (None when a custom factory decides)."""
        if not self.methods:
            raise InputError("--method: give at least one method")
        bad = [m for m in self.methods if known is not None and m not in known]
        if bad:
            raise InputError(f"--method: unknown {', '.join(bad)}; choose from {', '.join(known or ())}")
        if self.seeds < 1 or self.workers < 1:
            raise InputError(f"--seeds and --workers must be >= 1 (got {self.seeds}, {self.workers})")
        if self.limit is not None and self.limit < 1:
            raise InputError(f"--limit must be >= 1, got {self.limit}")
        parse_keyframes(self.keyframes)
        if isinstance(self.method_opts.get("top_k"), dict) and not per_tool_top_k_supported():
            raise InputError("--top-k per tool (e.g. time=200,text=30,position=1) is not supported by this version's "
                             "methods; give one number")  # fmt: skip

    def run_dir(self) -> Path:
        if self.out:
            return Path(self.out)
        kind = self.dataset.partition(":")[0]
        emb = self.embedder.rsplit("/", 1)[-1]
        name = self.name or "_".join(p for p in (kind, "+".join(self.methods), emb, self.vlm or "") if p)
        day = datetime.now(timezone.utc).strftime("%Y-%m-%d")
        return Path(self.runs_dir) / day / re.sub(r"[^A-Za-z0-9._+-]+", "-", name)

    def identity(self) -> dict[str, Any]:
        d = asdict(self)
        return {k: d[k] for k in IDENTITY}


def per_tool_top_k_supported() -> bool:
    """Whether the agent takes a {tool: k} top_k (its signature says so), so a dict is never
    handed to a method that would fail on every question with it."""
    import inspect

    from ..agent.loop import Agent

    ann = inspect.signature(Agent.__init__).parameters.get("top_k")
    return ann is not None and "dict" in str(ann.annotation)


# ------------------------------------------------------------------------------------ rows on disk
class AnswerLog:
    """answers.jsonl: append + flush + fsync per row; a torn last line (crash) is dropped on open."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self._lock = threading.Lock()
        self.skipped_lines = 0
        if path.exists():
            data = path.read_bytes()
            if data and not data.endswith(b"\n"):
                atomic_write(path, data[: data.rfind(b"\n") + 1])

    def rows(self) -> list[dict[str, Any]]:
        """All rows, the last one per key winning (a retried question replaces its failure)."""
        out: dict[str, dict[str, Any]] = {}
        if not self.path.exists():
            return []
        with open(self.path, encoding="utf-8") as f:
            for line in f:
                if not line.strip():
                    continue
                try:
                    row = json.loads(line)
                    out[row["key"]] = row
                except (json.JSONDecodeError, KeyError, TypeError):
                    self.skipped_lines += 1
        return list(out.values())

    def append(self, row: dict[str, Any]) -> None:
        line = json.dumps(row, default=_json_default) + "\n"
        with self._lock, open(self.path, "a", encoding="utf-8") as f:
            f.write(line)
            f.flush()
            os.fsync(f.fileno())


def _json_default(o: Any) -> Any:
    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


def read_rows(run_dir: str | Path) -> list[dict[str, Any]]:
    """Rows of every answers.jsonl under a folder (one run or a folder of runs)."""
    root = Path(run_dir)
    files = (
        [root / "answers.jsonl"] if (root / "answers.jsonl").exists() else sorted(root.rglob("answers.jsonl"))
    )
    if not files:
        raise InputError(f"{root}: no answers.jsonl found (is this a run folder?)")
    rows: list[dict[str, Any]] = []
    for f in files:
        for r in AnswerLog(f).rows():
            r.setdefault("run", f.parent.name)
            rows.append(r)
    return rows


def row_key(ep: Episode, q: Question, method: str, seed: int) -> str:
    return f"{ep.id}|{q.id}|{method}|{seed}"


def derived_seed(seed: int, qid: str) -> int:
    return int(hashlib.sha256(f"{seed}:{qid}".encode()).hexdigest()[:8], 16)


# ------------------------------------------------------------------------------------ the run
MethodFactory = Callable[..., Any]


def _default_factory(name: str, memory: Any, **opts: Any) -> Any:
    from ..agent import create_method

    return create_method(name, memory, **opts)


class Runner:
    """Run a RunConfig (see `run`). `method_factory(name, memory, **opts)` and `embedder` may be
    given for tests or custom methods; by default the agent's `create_method` and `--embedder`."""

    def __init__(self, cfg: RunConfig, method_factory: MethodFactory | None = None, embedder: Any = None,
                 episodes: list[Episode] | None = None, log: Callable[[str], None] | None = None) -> None:  # fmt: skip
        cfg.validate(None if method_factory is not None else METHOD_NAMES)
        self.cfg = cfg
        self.factory = method_factory or _default_factory
        self._embedder = embedder
        self._episodes = episodes
        self.log = log or (lambda msg: print(msg, file=sys.stderr))
        self.thresholds = Thresholds.from_dict(cfg.thresholds)
        self.embedder_label = str(getattr(embedder, "name", "")) or cfg.embedder
        self.dir = cfg.run_dir()
        self.judge: Any = None
        self.vlm_cfg: Any = None

    # -------------------------------------------------------------- setup
    def _open_dir(self) -> AnswerLog:
        self.dir.mkdir(parents=True, exist_ok=True)
        cfg_path = self.dir / "config.json"
        log = AnswerLog(self.dir / "answers.jsonl")
        if cfg_path.exists():
            old = json.loads(cfg_path.read_text(encoding="utf-8"))
            diff = [k for k in IDENTITY if old.get(k) != self.cfg.identity()[k]]
            if diff and log.path.exists() and log.rows():
                raise InputError(f"{self.dir} holds a run with other settings ({', '.join(diff)}); "
                                 f"use another --out/--name, or delete the folder")  # fmt: skip
            methods = list(dict.fromkeys(list(old.get("methods", [])) + self.cfg.methods))
            seeds = max(int(old.get("seeds", 1)), self.cfg.seeds)
        else:
            methods, seeds = self.cfg.methods, self.cfg.seeds
        doc = asdict(self.cfg) | {"methods": methods, "seeds": seeds, "updated": _now()}
        atomic_write_json(cfg_path, doc, indent=2, default=str)
        return log

    def _make_embedder(self) -> CachingEmbedder:
        from ..embed.base import create_embedder

        inner = self._embedder if self._embedder is not None else create_embedder(self.cfg.embedder)
        return CachingEmbedder(inner, Path(self.cfg.cache_dir) / "embeddings")

    def _setup_models(self) -> None:
        from ..agent.config import VLMConfig

        if any(m in VLM_METHODS for m in self.cfg.methods) or self.cfg.vlm:
            self.vlm_cfg = VLMConfig.resolve(model=self.cfg.vlm, base_url=self.cfg.vlm_base_url)
        if self.cfg.judge_model:
            from .judge import Judge

            jc = VLMConfig.resolve(
                model=self.cfg.judge_model, base_url=self.cfg.judge_base_url or self.cfg.vlm_base_url
            )
            self.judge = Judge(jc)

    def episodes(self) -> list[Episode]:
        eps = self._episodes if self._episodes is not None else load_dataset(
            self.cfg.dataset, queries=self.cfg.queries, **self.cfg.dataset_opts)  # fmt: skip
        if self.cfg.episodes:
            eps = [e for e in eps if fnmatch(e.id, self.cfg.episodes)]
            if not eps:
                raise InputError(f"--episodes {self.cfg.episodes!r} matches no episode")
        if self.cfg.limit is not None:
            left, out = self.cfg.limit, []
            for e in eps:
                if left <= 0:
                    break
                e.questions = e.questions[:left]
                left -= len(e.questions)
                out.append(e)
            eps = out
        return eps

    # -------------------------------------------------------------- main loop
    def run(self, source_for: Callable[[Episode], Any] | None = None, keyframes: KeyframeConfig | None = None,
            extra_key: dict[str, Any] | None = None) -> dict[str, Any]:  # fmt: skip
        """Answer every pending (question, method, seed); write rows; return the summary."""
        log = self._open_dir()
        done = {r["key"] for r in log.rows() if not (self.cfg.retry_failed and r["answer"].get("failed"))}
        eps = self.episodes()
        todo = [(e, [(q, m, s) for q in e.questions for m in self.cfg.methods for s in range(self.cfg.seeds)
                     if row_key(e, q, m, s) not in done]) for e in eps]  # fmt: skip
        total = sum(len(t) for _, t in todo)
        kf = keyframes or parse_keyframes(self.cfg.keyframes)
        self.log(f"eval: {len(eps)} episode(s), {total} answer(s) to run ({len(done)} already in {self.dir})")
        show = sys.stderr.isatty() if self.cfg.progress is None else self.cfg.progress
        if total:
            self._setup_models()
            emb = self._make_embedder()
            bar = tqdm(total=total, desc="eval", unit="q", disable=not show, file=sys.stderr)
            try:
                for ep, items in todo:
                    if items:
                        self._run_episode(ep, items, emb, kf, log, bar, source_for, extra_key)
            finally:
                bar.close()
                emb.close()
        rows = log.rows()
        summary = summarize(rows, self.thresholds)
        summary["run_dir"] = str(self.dir)
        atomic_write_json(self.dir / "summary.json", summary, indent=2, default=_json_default)
        return summary

    def _run_episode(self, ep: Episode, items: list[tuple[Question, str, int]], emb: CachingEmbedder,
                     kf: KeyframeConfig, log: AnswerLog, bar: Any, source_for: Callable[[Episode], Any] | None,
                     extra_key: dict[str, Any] | None) -> None:  # fmt: skip
        src = source_for(ep) if source_for is not None else None
        mem, info = build_memory(ep, Path(self.cfg.cache_dir), emb, kf, ocr=self.cfg.ocr,
                                 thumb_size=self.cfg.thumb_size, source=src, extra=extra_key)  # fmt: skip
        try:
            n_mem = mem.count()
            if n_mem == 0:
                raise InputError(
                    f"episode {ep.id}: no frame was kept in memory (check poses and --keyframes)"
                )
            t0 = ep.t0 if ep.t0 is not None else (info.get("first_t") or mem.time_span()[0])
            span = mem.time_span()
            for q in ep.questions:
                q.truth.resolve(float(t0))
                q.horizon = q.horizon or horizon_of(span[1] - span[0])
            mem_info = {"key": info.get("key"), "memories": n_mem, "frames": info.get("frames")}
            pools: dict[tuple[str, int], queue.Queue[Any]] = {}
            for m in dict.fromkeys(m for _, m, _ in items):
                for s in {s for _, mm, s in items if mm == m}:
                    pools[(m, s)] = queue.Queue()
                    if m != "random":  # build one up front: first-time work (captions) runs once, here
                        pools[(m, s)].put(self._method(m, mem, s))
            with ThreadPoolExecutor(max_workers=self.cfg.workers) as pool:
                futs = [pool.submit(self._answer_one, ep, q, m, s, mem, pools[(m, s)], mem_info)
                        for q, m, s in items]  # fmt: skip
                for fut in as_completed(futs):
                    log.append(fut.result())
                    bar.update(1)
        finally:
            mem.close()

    def _method(self, name: str, mem: Any, seed: int) -> Any:
        opts = dict(self.cfg.method_opts)
        opts["seed"] = seed
        if name in VLM_METHODS and self.vlm_cfg is not None:
            opts["vlm"] = self.vlm_cfg
        try:
            return self.factory(name, mem, **opts)
        except TypeError as e:  # e.g. an option value of a shape this method does not take
            shown = {k: v for k, v in opts.items() if k != "vlm"}
            raise InputError(f"method {name} cannot be built with options {shown}: {e}") from e

    @contextmanager
    def _borrow(self, name: str, mem: Any, seed: int, qid: str, pool: queue.Queue[Any]) -> Iterator[Any]:
        if name == "random":
            yield self._method(name, mem, derived_seed(seed, qid))
            return
        try:
            inst = pool.get_nowait()
        except queue.Empty:
            inst = self._method(name, mem, seed)
        try:
            yield inst
        finally:
            pool.put(inst)

    def _answer_one(self, ep: Episode, q: Question, method: str, seed: int, mem: Any, pool: queue.Queue[Any],
                    mem_info: dict[str, Any]) -> dict[str, Any]:  # fmt: skip
        start = time.perf_counter()
        try:
            image = read_image(q.image) if q.image is not None else None
            with self._borrow(method, mem, seed, q.id, pool) as m:
                ans = m.ask(q.text, image=image)
            if not isinstance(ans, Answer):
                raise TypeError(f"method {method} returned {type(ans).__name__}, not an Answer")
        except Exception as e:  # noqa: BLE001 - one failing question must not end the run; it is recorded
            ans = Answer(
                question=q.text, method=method, failed=True, found=False, error=f"{type(e).__name__}: {e}"
            )
        wall = time.perf_counter() - start
        uses_vlm = method in VLM_METHODS and self.vlm_cfg is not None and self.vlm_cfg.configured
        verdict = None
        if q.type == "text" and self.judge is not None and not ans.failed:
            verdict = self.judge.grade(q.text, q.truth.text, ans.text)
        return build_row(ep, q, method, seed, ans, thr=self.thresholds, dataset=self.cfg.dataset,
                         embedder=self.embedder_label, vlm=self.vlm_cfg.model if uses_vlm else None, run=self.dir.name,
                         mem_info=mem_info, wall_s=wall, judge=verdict, variant=self.cfg.variant)  # fmt: skip


def build_row(ep: Episode, q: Question, method: str, seed: int, ans: Answer, thr: Thresholds, dataset: str = "",
              embedder: str = "", vlm: str | None = None, run: str = "", mem_info: dict[str, Any] | None = None,
              wall_s: float = 0.0, judge: dict[str, Any] | None = None, variant: str = "") -> dict[str, Any]:  # fmt: skip
    """One answers.jsonl row: the question, its truth, the full answer, the prediction and its score."""
    row: dict[str, Any] = {
        "key": row_key(ep, q, method, seed), "run": run, "dataset": dataset, "episode": ep.id, "qid": q.id,
        "method": method, "seed": seed, "embedder": embedder, "vlm": vlm, "question": q.to_dict(),
        "truth": truth_row(q, ep), "pred": prediction(ans, q, ep), "answer": ans.model_dump(mode="json"),
        "pos_threshold": ep.pos_threshold, "frame_tol": ep.frame_tol, "memory": mem_info or {},
        "wall_s": round(wall_s, 4), "finished": _now(), "variant": variant,
    }  # fmt: skip
    if judge is not None:
        row["judge"] = judge
    row["score"] = score_row(row, thr)
    return row


def _now() -> str:
    return datetime.now(timezone.utc).isoformat(timespec="seconds")


def run(cfg: RunConfig, **kwargs: Any) -> dict[str, Any]:
    """Run an evaluation (see RunConfig) and return its summary (also in RUN_DIR/summary.json)."""
    return Runner(cfg, **kwargs).run()


def rejudge(run_dir: str | Path, judge: Any, thresholds: Thresholds | None = None) -> int:
    """Judge the text answers of a run that have no verdict yet (e.g. run without --judge);
    rewrites answers.jsonl atomically and refreshes summary.json. Returns how many were judged."""
    root = Path(run_dir)
    path = root / "answers.jsonl"
    if not path.exists():
        raise InputError(f"{root}: no answers.jsonl (give one run folder)")
    cfg = root / "config.json"
    thr = thresholds or Thresholds.from_dict(json.loads(cfg.read_text(encoding="utf-8")).get("thresholds")
                                             if cfg.exists() else None)  # fmt: skip
    rows = AnswerLog(path).rows()
    n = 0
    for r in rows:
        if r["question"]["type"] != "text" or r["answer"].get("failed"):
            continue
        if (r.get("judge") or {}).get("correct") is not None:
            continue
        r["judge"] = judge.grade(
            r["question"]["text"], r["truth"].get("text", []), r["answer"].get("text", "")
        )
        r["score"] = score_row(r, thr)
        n += 1
    with atomic_open(path, "w") as f:
        for r in rows:
            f.write(json.dumps(r, default=_json_default) + "\n")
    summary = summarize(rows, thr) | {"run_dir": str(root)}
    atomic_write_json(root / "summary.json", summary, indent=2, default=_json_default)
    return n
