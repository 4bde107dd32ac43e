"""The evaluation runner: dataset x methods x seeds -> one JSONL row per answer, resumable.

A run folder (`runs/<date>/<name>/` by default) holds `config.json`, `manifest.json` (what
was evaluated and how, `ravenmem.eval.recording`), `answers.jsonl` (one row per question x
method x seed, appended and flushed as each answer arrives), `model_io.jsonl` (every model
request and reply) and `summary.json`.
Running the same command again skips rows already present, so a crashed or interrupted run
resumes where it stopped; a different configuration in the same folder is refused. Questions
run in parallel on a bounded thread pool; each worker borrows its own method instance (the
agent keeps per-question cost counters), except `random`, built per question from a seed derived
from (seed, question id) so its answers do not depend on scheduling.
"""

from __future__ import annotations

import hashlib
import json
import queue
import sys
import threading
import time
from collections.abc import Callable, Iterator
from concurrent.futures import ThreadPoolExecutor, as_completed
from contextlib import contextmanager
from datetime import datetime, timezone
from fnmatch import fnmatch
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from ..agent.ask import AskRequest, ask
from ..agent.schema import Answer
from ..errors import InputError
from ..fsio import atomic_open, atomic_write, atomic_write_json
from ..imageio import read_image
from ..ingest.keyframes import KeyframeConfig
from .cache import CachingEmbedder, build_memory
from .config import IDENTITY, RunConfig, Thresholds
from .datasets import load_dataset
from .metrics import prediction, score_row, summarize, truth_row
from .recording import MANIFEST, MODEL_IO, SETUP, ModelLog, RecordingClient, append_json_line, manifest
from .types import Episode, Question, horizon_of

# Options of the contract between the evaluator and the VLM agent: checked against the agent's
# signature before a run, so a study never varies an option this version would silently drop.
AGENT_OPTIONS = ("show_scores", "time_mode", "preset", "temperature")


def method_names() -> list[str]:
    """Every method the registry can build (built-ins and entry points), without importing them."""
    from ..agent.base import METHODS

    return METHODS.names()


def agent_takes(option: str) -> bool:
    """Whether this version's methods take `option`: it is a field of the one options model,
    `MethodOptions` (a preset is applied there, the rest read by the methods)."""
    from dataclasses import fields

    from ..agent.ask import MethodOptions

    return option in {f.name for f in fields(MethodOptions)}


def per_tool_top_k_supported() -> bool:
    """Whether `MethodOptions.top_k` takes {tool: k} (it does since per-tool k exist; kept so an
    evaluation config states the contract it relies on)."""
    from ..agent.ask import MethodOptions

    return MethodOptions.of(top_k={"text": 1}).check().top_k == {"text": 1}


def check_methods(cfg: RunConfig) -> None:
    """Refuse unknown method names and agent options this version's agent does not take."""
    known = method_names()
    bad = [m for m in cfg.methods.names if m not in known]
    if bad:
        raise InputError(f"--method: unknown {', '.join(bad)}; choose from {', '.join(known)}")
    if "raven" not in cfg.methods.names:
        return
    opts = cfg.methods.options()
    if isinstance(opts.get("top_k"), dict) and not per_tool_top_k_supported():
        raise InputError(
            "--top-k per tool (e.g. time=200,text=30,position=1) is not supported by this version's "
            "methods; give one number"
        )
    missing = [o for o in AGENT_OPTIONS if o in opts and not agent_takes(o)]
    if missing:
        flags = ", ".join("--" + o.replace("_", "-") for o in missing)
        raise InputError(f"{flags}: this version's raven method does not take {', '.join(missing)}")


def preset_notes(cfg: RunConfig) -> list[str]:
    """What of the preset this version's agent cannot apply (said, never silently dropped)."""
    from ..agent.presets import get_preset

    p = get_preset(cfg.methods.preset)
    if p is None or "raven" not in cfg.methods.names:
        return []
    return [
        f"preset {p.name}: {k}={v} not applied (this version's raven agent takes no {k!r})"
        for k, v in p.options().items()
        if k in p.hooks and not agent_takes(k)
    ]


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
        with self._lock:
            append_json_line(self.path, row, _json_default)


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


def _needs_vlm(name: str) -> bool:
    from ..agent.base import METHODS, needs_vlm

    return name in METHODS.names() and needs_vlm(name)


class Runner:
    """Run a RunConfig (see `run`). `method_factory(name, memory, **opts)` and `embedder` may be
    given for tests or custom methods; by default the agent's `create_method` and the config's
    embedder. A method that needs a VLM stops the run before any question when none is set."""

    def __init__(
        self,
        cfg: RunConfig,
        method_factory: MethodFactory | None = None,
        embedder: Any = None,
        episodes: list[Episode] | None = None,
        log: Callable[[str], None] | None = None,
    ) -> None:
        if method_factory is None:
            check_methods(cfg)
        self.cfg = cfg
        self.factory = method_factory or _default_factory
        self._embedder = embedder
        self._episodes = episodes
        self.log = log or (lambda msg: print(msg, file=sys.stderr))
        self.thresholds = cfg.thresholds
        self.embedder_label = str(getattr(embedder, "name", "")) or cfg.models.embedder
        self.dir = cfg.run_dir()
        self.judge: Any = None
        self.vlm_cfg: Any = None
        self.model_log = ModelLog(self.dir / MODEL_IO)

    # -------------------------------------------------------------- setup
    def _open_dir(self) -> AnswerLog:
        self.dir.mkdir(parents=True, exist_ok=True)
        cfg_path = self.dir / "config.json"
        log = AnswerLog(self.dir / "answers.jsonl")
        ident = self.cfg.identity()
        doc = self.cfg.to_json()
        if cfg_path.exists():
            old = read_json(cfg_path)
            diff = [k for k in IDENTITY if old.get(k) != ident[k]]
            if diff and log.path.exists() and log.rows():
                raise InputError(
                    f"{self.dir} holds a run with other settings ({', '.join(diff)}); "
                    "use another --out/--name, or delete the folder"
                )
            doc["methods"] = list(dict.fromkeys(list(old.get("methods", [])) + doc["methods"]))
            doc["seeds"] = max(int(old.get("seeds", 1)), self.cfg.seeds)
        atomic_write_json(cfg_path, doc | {"updated": _now()}, indent=2, default=str)
        return log

    def _write_manifest(self, eps: list[Episode]) -> None:
        """manifest.json: written when the run starts; a resumed run keeps the first `created`."""
        from ..agent.presets import get_preset

        p = get_preset(self.cfg.methods.preset)
        doc = manifest(self.cfg, eps, p.options() if p else None)
        path = self.dir / MANIFEST
        if path.exists():
            doc["created"] = read_json(path).get("created", doc["created"])
            doc["updated"] = _now()
        atomic_write_json(path, doc, indent=2, default=str)

    def _make_embedder(self) -> CachingEmbedder:
        from ..embed.base import create_embedder

        inner = self._embedder if self._embedder is not None else create_embedder(self.cfg.models.embedder)
        self.embedder_label = str(getattr(inner, "name", "")) or self.embedder_label
        return CachingEmbedder(inner, Path(self.cfg.memory.cache_dir) / "embeddings")

    def _setup_models(self) -> None:
        """Resolve the VLM (and judge); refuse methods that need a VLM when none is configured."""
        from ..agent.config import VLMConfig

        models = self.cfg.models
        wanting = [m for m in self.cfg.methods.names if _needs_vlm(m)]
        if wanting or models.vlm:
            self.vlm_cfg = VLMConfig.resolve(model=models.vlm, base_url=models.vlm_base_url)
        if wanting and not self.vlm_cfg.configured:
            raise InputError(
                f"--method {', '.join(wanting)} needs a VLM and none is configured: give --vlm MODEL "
                "(and --vlm-base-url URL) or set RAVENMEM_VLM_MODEL / RAVENMEM_VLM_BASE_URL"
            )
        if models.judge:
            from .judge import Judge

            jc = VLMConfig.resolve(model=models.judge, base_url=models.judge_base_url or models.vlm_base_url)
            self.judge = Judge(jc, client=RecordingClient(jc, self.model_log))

    def episodes(self) -> list[Episode]:
        ds = self.cfg.dataset
        eps = (
            self._episodes
            if self._episodes is not None
            else load_dataset(ds.spec, queries=ds.queries, **ds.options())
        )
        if ds.episodes:
            eps = [e for e in eps if fnmatch(e.id, ds.episodes)]
            if not eps:
                raise InputError(f"--episodes {ds.episodes!r} matches no episode")
        if ds.limit is not None:
            left, out = ds.limit, []
            for e in eps:
                if left <= 0:
                    break
                e.questions = e.questions[:left]
                left -= len(e.questions)
                out.append(e)
            eps = out
        return eps

    # -------------------------------------------------------------- main loop
    def run(
        self,
        source_for: Callable[[Episode], Any] | None = None,
        keyframes: KeyframeConfig | None = None,
        extra_key: dict[str, Any] | None = None,
    ) -> dict[str, Any]:
        """Answer every pending (question, method, seed); write rows; return the summary."""
        self._setup_models()
        eps = self.episodes()
        self.thresholds.check_subsets({q.subset for e in eps for q in e.questions})
        log = self._open_dir()
        self._write_manifest(eps)
        notes = {n for e in eps for n in e.meta.get("notes", [])} | {
            str(e.meta["zone"]) for e in eps if e.meta.get("zone")
        }
        for note in sorted(notes) + preset_notes(self.cfg):
            self.log(f"eval: {note}")
        done = {r["key"] for r in log.rows() if not (self.cfg.retry_failed and r["answer"].get("failed"))}
        names, seeds = self.cfg.methods.names, range(self.cfg.seeds)
        todo = [
            (
                e,
                [
                    (q, m, s)
                    for q in e.questions
                    for m in names
                    for s in seeds
                    if row_key(e, q, m, s) not in done
                ],
            )
            for e in eps
        ]
        total = sum(len(t) for _, t in todo)
        kf = keyframes or self.cfg.memory.keyframe_config()
        self.log(f"eval: {len(eps)} episode(s), {total} answer(s) to run ({len(done)} already in {self.dir})")
        show = sys.stderr.isatty() if self.cfg.progress is None else self.cfg.progress
        if total:
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

    def _run_episode(
        self,
        ep: Episode,
        items: list[tuple[Question, str, int]],
        emb: CachingEmbedder,
        kf: KeyframeConfig,
        log: AnswerLog,
        bar: Any,
        source_for: Callable[[Episode], Any] | None,
        extra_key: dict[str, Any] | None,
    ) -> None:
        src = source_for(ep) if source_for is not None else None
        mcfg = self.cfg.memory
        mem, info = build_memory(
            ep,
            Path(mcfg.cache_dir),
            emb,
            kf,
            ocr=mcfg.ocr,
            thumb_size=mcfg.thumb_size,
            source=src,
            extra=extra_key,
        )
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
                        pools[(m, s)].put(self._method(m, mem, s, f"{ep.id}|{SETUP}|{m}|{s}"))
            with ThreadPoolExecutor(max_workers=self.cfg.workers) as pool:
                futs = [
                    pool.submit(self._answer_one, ep, q, m, s, mem, pools[(m, s)], mem_info)
                    for q, m, s in items
                ]
                for fut in as_completed(futs):
                    log.append(fut.result())
                    bar.update(1)
        finally:
            mem.close()

    def _method(self, name: str, mem: Any, seed: int, context: str = "") -> Any:
        opts = self.cfg.methods.options() | {"seed": seed}
        if self.vlm_cfg is not None and _needs_vlm(name):
            opts["vlm"] = RecordingClient(self.vlm_cfg, self.model_log, context)  # one per instance
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

    def _answer_one(
        self,
        ep: Episode,
        q: Question,
        method: str,
        seed: int,
        mem: Any,
        pool: queue.Queue[Any],
        mem_info: dict[str, Any],
    ) -> dict[str, Any]:
        start = time.perf_counter()
        try:
            image = read_image(q.image) if q.image is not None else None
            text = q.text
            if q.instructions and _needs_vlm(method):  # how to answer, for the model
                text = f"{q.text}\n{q.instructions}"
            with self._borrow(method, mem, seed, q.id, pool) as m:
                client = getattr(m, "client", None)
                if isinstance(client, RecordingClient):
                    client.context = row_key(ep, q, method, seed)
                ans = ask(mem, AskRequest(text, image=image), method=m).answer
            if not isinstance(ans, Answer):
                raise TypeError(f"method {method} returned {type(ans).__name__}, not an Answer")
        except Exception as e:  # noqa: BLE001 - one failing question must not end the run; it is recorded
            ans = Answer(
                question=q.text, method=method, failed=True, found=False, error=f"{type(e).__name__}: {e}"
            )
        wall = time.perf_counter() - start
        verdict = None
        if q.type == "text" and self.judge is not None and not ans.failed:
            verdict = self.judge.grade(
                q.text, q.truth.text, ans.text, context=f"judge|{row_key(ep, q, method, seed)}"
            )
        return build_row(
            ep,
            q,
            method,
            seed,
            ans,
            thr=self.thresholds,
            dataset=self.cfg.dataset.spec,
            ran=self._ran(method, ans),
            run=self.dir.name,
            mem_info=mem_info,
            wall_s=wall,
            judge=verdict,
            variant=self.cfg.variant,
        )

    def _ran(self, method: str, ans: Answer) -> dict[str, Any]:
        """The method, model and embedder that actually produced the answer: the answer's own
        record where it has one (`Answer.model`, `Answer.embedder`), else the run's settings."""
        uses_vlm = self.vlm_cfg is not None and self.vlm_cfg.configured and _needs_vlm(method)
        model = getattr(ans, "model", None) or (self.vlm_cfg.model if uses_vlm else None)
        embedder = getattr(ans, "embedder", None) or self.embedder_label
        return {"method": ans.method or method, "model": model, "embedder": embedder}


def build_row(
    ep: Episode,
    q: Question,
    method: str,
    seed: int,
    ans: Answer,
    thr: Thresholds,
    dataset: str = "",
    ran: dict[str, Any] | None = None,
    run: str = "",
    mem_info: dict[str, Any] | None = None,
    wall_s: float = 0.0,
    judge: dict[str, Any] | None = None,
    variant: str = "",
) -> dict[str, Any]:
    """One answers.jsonl row: the question, its truth, the full answer, the prediction and its score.

    `method` is the method asked for (the row's key); `ran` what actually answered (method,
    model, embedder), also copied to the row's `embedder` and `vlm` that reports group by."""
    ran = ran or {"method": ans.method or method, "model": None, "embedder": ""}
    row: dict[str, Any] = {
        "key": row_key(ep, q, method, seed),
        "run": run,
        "dataset": dataset,
        "episode": ep.id,
        "qid": q.id,
        "method": method,
        "seed": seed,
        "embedder": ran["embedder"],
        "vlm": ran["model"],
        "ran": ran,
        "question": q.to_dict(),
        "truth": truth_row(q, ep),
        "pred": prediction(ans, q, ep),
        "answer": ans.model_dump(mode="json"),
        "pos_threshold": ep.pos_threshold,
        "frame_tol": ep.frame_tol,
        "memory": mem_info or {},
        "wall_s": round(wall_s, 4),
        "finished": _now(),
        "variant": variant,
    }
    if ep.meta.get("time_rule"):
        row["time_rule"] = ep.meta["time_rule"]
    if ep.meta.get("notes"):
        row["dataset_notes"] = list(ep.meta["notes"])
    if ep.meta.get("zone"):
        row["zone"] = ep.meta["zone"]
    if judge is not None:
        row["judge"] = judge
    row["score"] = score_row(row, thr)
    return row


def _now() -> str:
    return datetime.now(timezone.utc).isoformat(timespec="seconds")


def run(cfg: RunConfig, **kwargs: Any) -> dict[str, Any]:
    """Run an evaluation (see RunConfig) and return its summary (also in RUN_DIR/summary.json)."""
    return Runner(cfg, **kwargs).run()


def read_json(path: Path) -> dict[str, Any]:
    """A run folder's JSON file (config.json, study.json); a damaged one is a one-line error."""
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as e:  # ValueError: not UTF-8, not JSON
        raise InputError(f"{path}: cannot read ({e})") from e
    if not isinstance(doc, dict):
        raise InputError(f"{path}: expected a JSON object")
    return doc


def run_thresholds(run_dir: Path) -> Thresholds:
    """The thresholds a run folder was scored with (its config.json), else the defaults."""
    cfg = run_dir / "config.json"
    if cfg.exists():
        return Thresholds.from_dict(read_json(cfg).get("thresholds"))
    return Thresholds()


def rejudge(run_dir: str | Path, judge: Any, thresholds: Thresholds | None = None) -> int:
    """Judge the text answers of a run that have no verdict yet (e.g. run without --judge);
    rewrites answers.jsonl atomically and refreshes summary.json. Returns how many were judged."""
    root = Path(run_dir)
    path = root / "answers.jsonl"
    if not path.exists():
        raise InputError(f"{root}: no answers.jsonl (give one run folder)")
    thr = thresholds or run_thresholds(root)
    rows = AnswerLog(path).rows()
    n = 0
    for r in rows:
        if r["question"]["type"] != "text" or r["answer"].get("failed"):
            continue
        if (r.get("judge") or {}).get("correct") is not None:
            continue
        r["judge"] = judge.grade(
            r["question"]["text"],
            r["truth"].get("text", []),
            r["answer"].get("text", ""),
            context=f"judge|{r['key']}",
        )
        r["score"] = score_row(r, thr)
        n += 1
    with atomic_open(path, "w") as f:
        for r in rows:
            f.write(json.dumps(r, default=_json_default) + "\n")
    summary = summarize(rows, thr) | {"run_dir": str(root)}
    atomic_write_json(root / "summary.json", summary, indent=2, default=_json_default)
    return n
