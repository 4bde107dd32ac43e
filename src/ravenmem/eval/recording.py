"""What makes a run reproducible: its manifest, and every model request and reply it made.

A run folder gets `manifest.json` (what was evaluated and how: the dataset's path and content
hash, every setting, the ravenmem version and git revision, the time zones the truths were read
in, the scoring rule) and `model_io.jsonl`: one line per HTTP attempt to a model (the agent, the
captioner, the judge), each with the row key it served (`context`), the request as sent (images
replaced by their size and digest) and the reply as received. `ravenmem eval --replay RUN`
checks a run against them (`ravenmem.eval.replay`).
"""

from __future__ import annotations

import hashlib
import json
import os
import subprocess
import sys
import threading
from collections.abc import Iterable
from dataclasses import asdict
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

from ..agent.client import VLMClient
from ..agent.config import VLMConfig
from .config import RunConfig
from .types import Episode

MANIFEST = "manifest.json"
MODEL_IO = "model_io.jsonl"
SETUP = "setup"  # the context of requests made while building a method (the caption baseline's captions)


def append_json_line(path: Path, obj: Any, default: Any = str) -> None:
    """Append one JSON line to a file, flushed and fsynced (a crash loses at most that line)."""
    line = json.dumps(obj, default=default) + "\n"
    with open(path, "a", encoding="utf-8") as f:
        f.write(line)
        f.flush()
        os.fsync(f.fileno())


class ModelLog:
    """model_io.jsonl: one JSON line per model exchange, appended and flushed as it happens."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self._lock = threading.Lock()

    def write(self, entry: dict[str, Any]) -> None:
        with self._lock:
            append_json_line(self.path, entry)

    def contexts(self) -> set[str]:
        """The row keys (and setup contexts) that have at least one recorded reply."""
        if not self.path.exists():
            return set()
        out = set()
        with open(self.path, encoding="utf-8") as f:
            for line in f:
                try:
                    entry = json.loads(line)
                except json.JSONDecodeError:
                    continue  # a torn last line from a crash
                if isinstance(entry, dict) and entry.get("response") is not None:
                    out.add(str(entry.get("context", "")))
        return out


class RecordingClient(VLMClient):
    """A VLMClient that writes every attempt (request, reply or error) to a ModelLog, labelled
    with `context` (the runner sets it to the row key before each question), and keeps the last
    reply, whose own answer fields the runner reads (`answer_forms.reply_fields`)."""

    def __init__(self, config: VLMConfig, log: ModelLog, context: str = "") -> None:
        super().__init__(config)
        self.log = log
        self.context = context
        self.last_reply: Any = None  # the last reply received (the runner reads the answer's own fields)

    def chat(self, messages: list[dict[str, Any]], *args: Any, **kwargs: Any) -> Any:
        first = len(self.events)
        try:
            self.last_reply = super().chat(messages, *args, **kwargs)
            return self.last_reply
        finally:
            for event in self.events[first:]:
                self.log.write({"context": self.context, "model": self.config.model, **event})


def git_revision() -> str | None:
    """The git commit of the ravenmem source that ran (with "+dirty" when it has local changes),
    None when it is not a git checkout."""
    src = Path(__file__).resolve().parents[3]
    if not (src / ".git").exists():
        return None
    try:
        rev = subprocess.run(
            ["git", "-C", str(src), "rev-parse", "HEAD"],
            capture_output=True,
            text=True,
            timeout=10,
            check=True,
        ).stdout.strip()
        dirty = subprocess.run(
            ["git", "-C", str(src), "status", "--porcelain", "--untracked-files=no"],
            capture_output=True,
            text=True,
            timeout=10,
        ).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return None
    return rev + ("+dirty" if dirty else "") if rev else None


def ravenmem_version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("ravenmem")
    except PackageNotFoundError:
        return "unknown"


def dataset_hash(episodes: Iterable[Episode]) -> str:
    """sha256 over what was evaluated: every episode's id, frame times and frame files, and
    every question with its truth (images are not read: the cache keys cover their content)."""
    h = hashlib.sha256()
    for ep in episodes:
        doc = {
            "id": ep.id,
            "frames": [round(t, 6) for t in ep.frame_times],
            "files": ep.frame_files,
            "questions": [q.to_dict() | {"truth": q.truth.to_dict()} for q in ep.questions],
        }
        h.update(json.dumps(doc, sort_keys=True, default=str).encode())
    return h.hexdigest()


def time_zones(episodes: Iterable[Episode]) -> list[str]:
    """How the truths' clock times were read, per dataset (NaVQA: the release's zone)."""
    return sorted({str(ep.meta.get("zone") or "UTC (recording clock)") for ep in episodes})


def manifest(cfg: RunConfig, episodes: list[Episode], preset: dict[str, Any] | None) -> dict[str, Any]:
    """The run's manifest (see the module docstring)."""
    spec = cfg.dataset.spec
    name, _, path = spec.partition(":")
    notes = sorted({n for ep in episodes for n in ep.meta.get("notes", [])})
    return {
        "ravenmem": ravenmem_version(),
        "git_revision": git_revision(),
        "python": sys.version.split()[0],
        "created": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        "dataset": {
            "spec": spec,
            "kind": name,
            "path": str(Path(path).resolve()) if name != "queries" else path,
            "queries": cfg.dataset.queries,
            "sha256": dataset_hash(episodes),
            "hash_covers": "episode ids, frame times and files, questions and truths as loaded",
            "episodes": len(episodes),
            "questions": sum(len(ep.questions) for ep in episodes),
            "split": cfg.dataset.split,
            "notes": notes,
        },
        "time_zones": time_zones(episodes),
        "methods": list(cfg.methods.names),
        "model": cfg.models.vlm,
        "vlm_base_url": cfg.models.vlm_base_url,
        "embedder": cfg.models.embedder,
        "preset": cfg.methods.preset,
        "preset_options": preset,
        "scoring": {"rule": cfg.thresholds.scoring, "thresholds": cfg.thresholds.to_dict()},
        "identity": cfg.identity(),
        "settings": json.loads(json.dumps(asdict(cfg), default=str)),
        "model_io": MODEL_IO,
    }


def reply_texts(reply: Any) -> list[str]:
    """The JSON texts of a chat reply: its content, then each tool call's arguments."""
    if reply is None:
        return []
    texts = [reply.content] if isinstance(getattr(reply, "content", None), str) else []
    return texts + [c.arguments for c in getattr(reply, "tool_calls", []) if isinstance(c.arguments, str)]
