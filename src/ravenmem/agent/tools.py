"""The memory tools as the model sees them, and the working memory of what it has been shown.

Each tool result lists every memory with its id, time, pose and similarity score (the scores
help the model weigh matches, so they are kept) and attaches the images of memories not shown
before; a memory already shown is listed by reference only, so no image is ever sent twice.
Time results come in forward chronological order; text and image results best first.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator

from ..errors import InputError, RavenmemError
from ..timeparse import fmt_time
from ..types import Hit, MemoryRecord
from .base import MemoryLike, record_image_url

TimeArg = float | str | None


class _Args(BaseModel):
    model_config = ConfigDict(extra="forbid")
    after: TimeArg = Field(None, description="only memories at or after this time")
    before: TimeArg = Field(None, description="only memories at or before this time")


class _Near(_Args):
    near: list[float] | None = Field(
        None, description="[x, y, radius] in metres: only memories taken inside this disc"
    )

    @field_validator("near")
    @classmethod
    def _disc(cls, v: list[float] | None) -> list[float] | None:
        if v is not None and (len(v) != 3 or v[2] <= 0):
            raise ValueError("near must be [x, y, radius] with radius > 0")
        return v


class TextArgs(_Near):
    query: str = Field(
        ..., min_length=1, description="what to look for, e.g. 'a red backpack' or text on a sign"
    )


class ImageArgs(_Near):
    pass


class TimeArgs(_Args):
    time: float | str = Field(
        ...,
        description="ISO time as shown in results, HH:MM:SS, seconds from the start ('+12s'), or '10 minutes ago'",
    )


class PositionArgs(_Args):
    x: float
    y: float
    z: float | None = None
    radius: float | None = Field(None, gt=0, description="only memories within this many metres")


_TIME_DOC = "a time: ISO as shown in results, HH:MM:SS, seconds from the start ('+12s'), or '10 minutes ago'"
_FILTERS: dict[str, Any] = {
    "after": {"type": "string", "description": "optional: only memories at or after this time"},
    "before": {"type": "string", "description": "optional: only memories at or before this time"},
}
_NEAR = {
    "near": {
        "type": "array",
        "items": {"type": "number"},
        "description": "optional [x, y, radius] in metres: only memories taken inside this disc",
    }
}


def _obj(props: dict[str, Any], required: list[str]) -> dict[str, Any]:
    return {"type": "object", "properties": props, "required": required}


# Plain JSON schemas (no anyOf / null / additionalProperties) so that every OpenAI-compatible
# server accepts them, Gemini's included; the pydantic models above do the validation.
TOOL_DOCS: dict[str, tuple[type[BaseModel], str, dict[str, Any]]] = {
    "search_text": (
        TextArgs,
        "Find memories whose image matches a text description (and text seen in the scene).",
        _obj(
            {
                "query": {"type": "string", "description": "what to look for, e.g. 'a red backpack'"},
                **_FILTERS,
                **_NEAR,
            },
            ["query"],
        ),
    ),
    "search_image": (
        ImageArgs,
        "Find memories that look like the image the user attached to the question.",
        _obj({**_FILTERS, **_NEAR}, []),
    ),
    "search_time": (
        TimeArgs,
        "List the memories from a given time onwards, in chronological order.",
        _obj({"time": {"type": "string", "description": _TIME_DOC}, **_FILTERS}, ["time"]),
    ),
    "search_position": (
        PositionArgs,
        "List the memories taken nearest to a map position (metres), nearest first.",
        _obj(
            {
                "x": {"type": "number"},
                "y": {"type": "number"},
                "z": {"type": "number", "description": "optional height; planar distance when omitted"},
                "radius": {
                    "type": "number",
                    "description": "optional: only memories within this many metres",
                },
                **_FILTERS,
            },
            ["x", "y"],
        ),
    ),
}


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
class ToolOutput:
    text: str
    images: list[tuple[MemoryRecord, str]]  # (record, data URL) of memories shown for the first time
    hits: list[Hit]
    ok: bool = True


def describe(rec: MemoryRecord, t0: float, score: float | None = None, distance: float | None = None) -> str:
    p = rec.pose
    parts = [
        f"[m{rec.id}] time {fmt_time(rec.t)} (+{rec.t - t0:.1f} s)",
        f"pose x={p.x:.2f} y={p.y:.2f} z={p.z:.2f} yaw={math.degrees(p.yaw):.0f}deg",
    ]
    if score is not None:
        parts.append(f"score {score:.3f}")
    if distance is not None:
        parts.append(f"distance {distance:.2f} m")
    if rec.ocr_text:
        parts.append(f"text seen: {json.dumps(rec.ocr_text[:120])}")
    return "; ".join(parts)


TOOL_KEYS = {
    "text": "search_text",
    "image": "search_image",
    "time": "search_time",
    "position": "search_position",
}


def per_tool_k(top_k: int | Mapping[str, int], default: int = 5) -> dict[str, int]:
    """{tool name: k} from one number for every tool, or a {tool: k} mapping such as
    {"time": 200, "text": 30, "position": 1} (FindingDory's settings); tools not named get `default`."""
    if isinstance(top_k, Mapping):
        ks = dict.fromkeys(TOOL_KEYS.values(), default)
        for key, val in top_k.items():
            name = TOOL_KEYS.get(key, key)
            if name not in ks:
                raise InputError(f"top_k: unknown tool {key!r}; use text, image, time or position")
            ks[name] = int(val)
    else:
        ks = dict.fromkeys(TOOL_KEYS.values(), int(top_k))
    if min(ks.values()) < 1:
        raise InputError(f"top_k must be >= 1 for every tool, got {top_k}")
    return ks


class ToolRunner:
    """Runs tool calls against a memory and formats what the model gets back.

    `text_search` replaces the memory's text tool (the caption baseline searches captions);
    `captions` adds a caption line to each memory; `attach_images=False` sends text only.
    """

    def __init__(
        self,
        mem: MemoryLike,
        top_k: int | Mapping[str, int] = 5,
        query_image: np.ndarray | None = None,
        text_search: Callable[..., list[Hit]] | None = None,
        captions: Callable[[int], str | None] | None = None,
        attach_images: bool = True,
        image_max_side: int = 0,
    ) -> None:
        self.ks = per_tool_k(top_k)
        self.top_k = max(self.ks.values())
        self.mem = mem
        self.query_image = query_image
        self.text_search = text_search or mem.search_text
        self.captions = captions
        self.attach_images = attach_images
        self.image_max_side = image_max_side
        self.t0 = mem.time_span()[0]
        self.images_sent = 0

    @property
    def names(self) -> list[str]:
        names = ["search_text", "search_time", "search_position"]
        if self.query_image is not None:
            names.insert(1, "search_image")
        return names

    def specs(self) -> list[dict[str, Any]]:
        """The tools in OpenAI function-calling form."""
        out = []
        for name in self.names:
            _, doc, params = TOOL_DOCS[name]
            doc = f"{doc} Returns up to {self.ks[name]} memories with time, pose and score."
            out.append(
                {"type": "function", "function": {"name": name, "description": doc, "parameters": params}}
            )
        return out

    def prompt_listing(self) -> str:
        """The tools described in words, for endpoints without function calling."""
        lines = []
        for spec in self.specs():
            fn = spec["function"]
            lines.append(
                f"- {fn['name']}: {fn['description']} Arguments (JSON schema): {json.dumps(fn['parameters'])}"
            )
        return "\n".join(lines)

    def run(self, name: str, arguments: str | dict[str, Any], wm: WorkingMemory) -> ToolOutput:
        """Execute one call; a bad call returns an error text the model can correct, never raises."""
        if name not in self.names:
            return ToolOutput(
                f"error: unknown tool {name!r}; available: {', '.join(self.names)}", [], [], ok=False
            )
        try:
            args = json.loads(arguments) if isinstance(arguments, str) else dict(arguments)
            if not isinstance(args, dict):
                raise ValueError("arguments must be a JSON object")
            hits, label = self._search(name, args)
        except (ValidationError, ValueError, TypeError, RavenmemError) as e:
            msg = str(e).replace("\n", " ")[:400]
            return ToolOutput(f"error: {name} could not run: {msg}", [], [], ok=False)
        return self._format(name, label, hits, wm)

    def _search(self, name: str, args: dict[str, Any]) -> tuple[list[Hit], str]:
        k, mem = self.ks[name], self.mem
        if name == "search_text":
            a = TextArgs.model_validate(args)
            near = _disc(a.near)
            hits = self.text_search(a.query, k=k, after=a.after, before=a.before, near=near)
            return hits, f"search_text({json.dumps(a.query)})"
        if name == "search_image":
            b = ImageArgs.model_validate(args)
            assert self.query_image is not None
            near = _disc(b.near)
            return mem.search_image(
                self.query_image, k=k, after=b.after, before=b.before, near=near
            ), "search_image()"
        if name == "search_time":
            c = TimeArgs.model_validate(args)
            hits = mem.search_time(c.time, k=k, after=c.after, before=c.before)
            return sorted(hits, key=lambda h: h.memory.t), f"search_time({json.dumps(c.time)})"
        d = PositionArgs.model_validate(args)
        hits = mem.search_position(d.x, d.y, d.z, k=k, radius=d.radius, after=d.after, before=d.before)
        return hits, f"search_position(x={d.x:g}, y={d.y:g})"

    def _format(self, name: str, label: str, hits: list[Hit], wm: WorkingMemory) -> ToolOutput:
        order = (
            "chronological"
            if name == "search_time"
            else ("nearest first" if name == "search_position" else "best first")
        )
        lines = [f"{label} -> {len(hits)} memories, {order}:" if hits else f"{label} -> no memories matched."]
        images: list[tuple[MemoryRecord, str]] = []
        for h in hits:
            rec = h.memory
            cap = self.captions(rec.id) if self.captions else None
            new = wm.add(h, name, cap)
            line = describe(rec, self.t0, h.score, h.distance)
            if cap:
                line += f"; caption: {json.dumps(cap)}"
            if not new:
                line += " (already shown above)"
            elif self.attach_images:
                url = self._image(rec)
                line += " (image attached below)" if url else " (no image stored)"
                if url:
                    images.append((rec, url))
            lines.append(line)
        return ToolOutput("\n".join(lines), images, hits)

    def _image(self, rec: MemoryRecord) -> str | None:
        return record_image_url(self.mem, rec, self.image_max_side)


def _disc(v: list[float] | None) -> tuple[float, float, float] | None:
    return (v[0], v[1], v[2]) if v else None


def image_parts(images: list[tuple[MemoryRecord, str]], detail: str | None = None) -> list[dict[str, Any]]:
    """Chat content parts: a label then the image, per memory."""
    parts: list[dict[str, Any]] = []
    for rec, url in images:
        parts.append({"type": "text", "text": f"[m{rec.id}] at {fmt_time(rec.t)}:"})
        img: dict[str, Any] = {"url": url}
        if detail:
            img["detail"] = detail
        parts.append({"type": "image_url", "image_url": img})
    return parts
