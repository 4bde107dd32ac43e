"""The memory tools as the model sees them, and the working memory of what it has been shown.

The tools themselves (names, argument models, what they run) are `ravenmem.tools.TOOLS`: the
function schemas sent to the model, the checking of its arguments and the searches all come
from that table. This module adds what only the agent needs: one k per tool, the text of each
result, and the images. Each result lists every memory with its id, time, pose and (unless
hidden) its similarity score or distance, and attaches the images of memories not shown
before; a memory already shown is listed by reference only, so no image is ever sent twice.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, cast

import numpy as np

from ..errors import InputError, RavenmemError
from ..memory.places import ChangeHit
from ..memory.protocol import MemoryLike, check_k
from ..timeparse import fmt_time
from ..tools import TOOLS, TimeMode, get_tool
from ..types import Hit, MemoryRecord
from .images import data_url, record_jpeg
from .schema import Answer, PlaceChange

DEFAULT_K = 5
TIME_MODES = ("forward", "centred", "nearest")


@dataclass
class Shown:
    record: MemoryRecord
    score: float | None
    distance: float | None
    tool: str
    caption: str | None = None


@dataclass
class WorkingMemory:
    """Every memory shown to the model during one question, in the order first shown."""

    items: dict[int, Shown] = field(default_factory=dict)
    changes: dict[int, dict[str, Any]] = field(default_factory=dict)  # latest mode: id -> place

    def __contains__(self, mid: object) -> bool:
        return mid in self.items

    def __len__(self) -> int:
        return len(self.items)

    def add(self, hit: Hit, tool: str, caption: str | None = None) -> bool:
        """Remember a hit; True when the memory is new (its image must be sent)."""
        old = self.items.get(hit.memory.id)
        if old is not None:
            if hit.score is not None and (old.score is None or hit.score > old.score):
                old.score = hit.score
            return False
        self.items[hit.memory.id] = Shown(hit.memory, hit.score, hit.distance, tool, caption)
        return True

    def ranked(self) -> list[Shown]:
        """Best first: scored memories by score, then the rest in the order shown."""
        scored = sorted(
            (s for s in self.items.values() if s.score is not None), key=lambda s: -(s.score or 0.0)
        )
        return scored + [s for s in self.items.values() if s.score is None]


@dataclass
class SentImage:
    record: MemoryRecord
    url: str
    nbytes: int


@dataclass
class ToolOutput:
    text: str
    images: list[SentImage]  # memories shown for the first time
    hits: list[Hit]
    ok: bool = True


def describe(
    rec: MemoryRecord,
    t0: float,
    score: float | None = None,
    distance: float | None = None,
    scores: bool = True,
) -> str:
    """One memory as the model reads it: `[m12] time ... (+12.3 s); pose x= y= z= yaw=deg; score`."""
    p = rec.pose
    parts = [
        f"[m{rec.id}] time {fmt_time(rec.t)} (+{rec.t - t0:.1f} s)",
        f"pose x={p.x:.2f} y={p.y:.2f} z={p.z:.2f} yaw={math.degrees(p.yaw):.0f}deg",
    ]
    if scores and score is not None:
        parts.append(f"score {score:.3f}")
    if scores and distance is not None:
        parts.append(f"distance {distance:.2f} m")
    if rec.ocr_text:
        parts.append(f"text seen: {json.dumps(rec.ocr_text[:120])}")
    return "; ".join(parts)


def per_tool_k(top_k: int | Mapping[str, int], default: int = DEFAULT_K) -> dict[str, int]:
    """{tool name: k} from one number for every tool, or a {tool: k} mapping such as
    {"time": 200, "text": 30, "position": 1} (FindingDory's settings; keys are tool names or
    their short keys); tools not named get `default`. Every k is checked by `check_k`."""
    if isinstance(top_k, Mapping):
        ks = dict.fromkeys(TOOLS, check_k(default))
        for key, val in top_k.items():
            try:
                name = get_tool(str(key)).name
            except InputError:
                raise InputError(f"top_k: unknown tool {key!r}; use text, image, time or position") from None
            ks[name] = check_k(val)
        return ks
    return dict.fromkeys(TOOLS, check_k(top_k))


def check_time_mode(mode: str) -> TimeMode:
    if mode not in TIME_MODES:
        raise InputError(f"time_mode must be forward, centred or nearest, got {mode!r}")
    return cast(TimeMode, mode)


class ToolRunner:
    """Runs the model's tool calls against a memory and writes what it gets back.

    `tools` limits the tools offered (all four by default); `text_search` replaces the
    memory's text search (the caption baseline searches captions); `captions` adds a caption
    line to each memory; `attach_images=False` sends text only; `labels` (records -> {id:
    words}) adds what each picture shows, for a model that cannot see (`agent.labels`);
    `show_scores=False` hides similarity scores and distances; `time_mode` picks the time
    tool's window; `diverse` (None: the tools' default) is the text and image tools'
    `diverse` where the model's call leaves it out, so a preset's "exactly k" holds.
    """

    def __init__(
        self,
        mem: MemoryLike,
        top_k: int | Mapping[str, int] = DEFAULT_K,
        query_image: np.ndarray | None = None,
        text_search: Callable[..., list[Hit]] | None = None,
        captions: Callable[[int], str | None] | None = None,
        attach_images: bool = True,
        image_max_side: int = 0,
        show_scores: bool = True,
        time_mode: str = "forward",
        tools: Sequence[str] | None = None,
        labels: Callable[[Sequence[MemoryRecord]], dict[int, list[str]]] | None = None,
        diverse: bool | None = None,
    ) -> None:
        self.diverse = diverse
        self.ks = per_tool_k(top_k)
        self.labels = labels
        self.mem = mem
        self.query_image = query_image
        self.text_search = text_search
        self.captions = captions
        self.attach_images = attach_images
        self.image_max_side = image_max_side
        self.show_scores = show_scores
        self.time_mode = check_time_mode(time_mode)
        self.names = [get_tool(n).name for n in (tools if tools is not None else TOOLS)]
        self.t0 = mem.time_span()[0]
        self.embedded = False  # a text or image search ran: the embedder took part in the answer

    @property
    def latest(self) -> bool:
        """Whether the text or image tool offers its latest mode here (it needs the memory's
        own embeddings: not with a replaced text search, as the caption baseline has)."""
        return self.text_search is None and bool({"search_text", "search_image"} & set(self.names))

    def specs(self) -> list[dict[str, Any]]:
        """The tools in OpenAI function-calling form, generated from `ravenmem.tools.TOOLS`."""
        out = []
        for name in self.names:
            tool = TOOLS[name]
            doc = tool.description(self.ks[name], scores=self.show_scores, time_mode=self.time_mode)
            params = tool.plain_schema()
            if not self.latest:
                params["properties"].pop("latest", None)
            fn = {"name": name, "description": doc, "parameters": params}
            out.append({"type": "function", "function": fn})
        return out

    def prompt_listing(self, schemas: bool = True) -> str:
        """The tools described in words, for endpoints without function calling. Without
        `schemas` (the server enforces them by constrained decoding) each tool is named with
        its arguments only, `search_text(query, after?, ...)`: a third of the prompt of a small
        local model, whose prompt processing dominates its time."""
        lines = []
        for spec in self.specs():
            fn = spec["function"]
            if schemas:
                params = json.dumps(fn["parameters"])
                lines.append(f"- {fn['name']}: {fn['description']} Arguments (JSON schema): {params}")
            else:
                req = fn["parameters"].get("required", [])
                args = req + [f"{a}?" for a in fn["parameters"].get("properties", {}) if a not in req]
                lines.append(f"- {fn['name']}({', '.join(args)}): {fn['description']}")
        return "\n".join(lines)

    def run(self, name: str, arguments: str | Mapping[str, Any], wm: WorkingMemory) -> ToolOutput:
        """Execute one call; a bad call returns an error text the model can correct, never raises."""
        if not name:
            return ToolOutput(
                f"error: a tool call without a tool name ({str(arguments)[:80]!r})", [], [], False
            )
        if name not in self.names:
            return ToolOutput(
                f"error: unknown tool {name!r}; available: {', '.join(self.names)}", [], [], False
            )
        tool = TOOLS[name]
        try:
            raw = json.loads(arguments) if isinstance(arguments, str) else arguments
            if not isinstance(raw, Mapping):
                raise InputError("arguments must be a JSON object")
            if self.diverse is not None and "diverse" in tool.args.model_fields and "diverse" not in raw:
                raw = {**raw, "diverse": self.diverse}
            args = tool.validate(raw)
            hits = tool.run(
                self.mem,
                args,
                self.ks[name],
                image=self.query_image,
                time_mode=self.time_mode,
                text_search=self.text_search,
            )
        except (RavenmemError, ValueError, TypeError, RecursionError) as e:
            msg = str(e).replace("\n", " ")[:400]
            return ToolOutput(f"error: {name} could not run: {msg}", [], [], ok=False)
        self.embedded = self.embedded or name in ("search_text", "search_image")
        mid = getattr(args, "memory_id", None)
        query = getattr(args, "query", None) or (f"m{mid}" if mid is not None else "the attached image")
        return self._format(tool.label(args), tool.order_for(args, self.time_mode), hits, name, wm, query)

    def _format(
        self, label: str, order: str, hits: list[Hit], name: str, wm: WorkingMemory, query: str = ""
    ) -> ToolOutput:
        lines = [f"{label} -> {len(hits)} memories, {order}:" if hits else f"{label} -> no memories matched."]
        changes = [h.change if isinstance(h, ChangeHit) else {} for h in hits]
        status = next((c.get("status") for c in changes if c), None)
        if status:
            note = changes[0].get("status_note")
            lines.append(f"status now: {status}" + (f" ({note})" if note else ""))
        images: list[SentImage] = []
        words = self.labels([h.memory for h in hits if h.memory.id not in wm]) if self.labels else {}
        for h, change in zip(hits, changes, strict=True):
            rec = h.memory
            cap = self.captions(rec.id) if self.captions else None
            new = wm.add(h, name, cap)
            line = describe(rec, self.t0, h.score, h.distance, self.show_scores)
            if h.count > 1 and h.span is not None:  # a consolidated memory (ravenmem consolidate)
                line += f"; stands for {h.count} memories seen from {fmt_time(h.span[0])} to {fmt_time(h.span[1])}"
            if cap:
                line += f"; caption: {json.dumps(cap)}"
            if words.get(rec.id):
                line += f"; picture shows (labels): {', '.join(words[rec.id])}"
            if change:
                wm.changes.setdefault(rec.id, {**change, "query": query})
                if change.get("role") == "sighting":
                    line += (
                        f"; latest sighting at place {change['place']}: {change['verdict']}. {change['text']}"
                    )
                else:
                    line += f"; a later view of place {change['place']} (last seen there in m{change['last_seen_id']}) without it"
            if not new:
                line += " (already shown above)"
            elif self.attach_images:
                img = record_image(self.mem, rec, self.image_max_side)
                line += " (image attached below)" if img else " (no image stored)"
                if img:
                    images.append(img)
            lines.append(line)
        return ToolOutput("\n".join(lines), images, hits)


def record_image(mem: MemoryLike, rec: MemoryRecord, max_side: int = 0) -> SentImage | None:
    """A memory's picture ready to send, or None when it has none that is safe to send."""
    jpeg = record_jpeg(mem, rec, max_side)
    return SentImage(rec, data_url(jpeg), len(jpeg)) if jpeg is not None else None


def image_parts(images: Sequence[SentImage], detail: str | None = None) -> list[dict[str, Any]]:
    """Chat content parts: a label then the image, per memory."""
    parts: list[dict[str, Any]] = []
    for im in images:
        parts.append({"type": "text", "text": f"[m{im.record.id}] at {fmt_time(im.record.t)}:"})
        img: dict[str, Any] = {"url": im.url}
        if detail:
            img["detail"] = detail
        parts.append({"type": "image_url", "image_url": img})
    return parts


def attach_changes(answer: Answer, wm: WorkingMemory) -> None:
    """Give the answer the places (latest mode) its evidence rests on, and warn when it rests on
    a sighting at a place the robot later saw without the thing. With no such evidence, an
    answer that says "not found" gets every place the latest mode reported (the reason why)."""
    ids = [e.id for e in answer.evidence]
    places: dict[tuple[str, int], dict[str, Any]] = {}
    for mid in ids:
        ch = wm.changes.get(mid)
        if ch is not None:
            places.setdefault((ch["query"], ch["place"]), ch)
    if not places and not answer.found:
        for ch in wm.changes.values():
            places.setdefault((ch["query"], ch["place"]), ch)
    answer.changes = [PlaceChange.model_validate(ch) for ch in places.values()]
    first = wm.changes.get(ids[0]) if ids and answer.found else None
    if first is not None and first.get("role") == "sighting" and first["verdict"] in ("moved", "gone"):
        answer.notes.append(
            f"warning: evidence m{ids[0]} is the last sighting at place {first['place']}, which the robot "
            f"looked at again later without it ({first['verdict']}): {first['text']}"
        )
