"""The four retrieval tools, described once.

Every front end reaches the memory through this table: the agent's function-calling schemas,
the `ravenmem search` command, the HTTP routes and the MCP tools are all generated from it, so a
tool's name, its arguments (one pydantic model, one description per argument), the `Memory`
method it calls and the order of its results are written in one place only.

    from ravenmem.tools import TOOLS
    tool = TOOLS["search_text"]
    args = tool.validate({"query": "a red mug", "after": "10 minutes ago"})
    hits = tool.run(mem, args, k=5)

`k` is not an argument of the models: the agent's k is a setting of the run (the paper fixes it
per dataset), while the CLI, HTTP and MCP take it from the caller and check it with `ravenmem.memory.check_k`.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Annotated, Any, Literal

import numpy as np
from pydantic import BaseModel, BeforeValidator, ConfigDict, Field, ValidationError, field_validator

from .errors import InputError
from .memory.diversity import SAME_VIEW
from .memory.protocol import MAX_K, MemoryLike, check_k
from .timeparse import fmt_time
from .types import MAX_COORD, MAX_ID, RANGES, T_MAX, Hit, MemoryRecord, Region, check_id

TimeArg = float | str
Order = Literal["best first", "chronological", "nearest first"]
LATEST_ORDER = "newest place first (its latest sighting, then later views without the thing)"
TimeMode = Literal["forward", "centred", "nearest"]
NEAREST_ORDER = "nearest in time first"

_TIME_DOC = (
    "a time: ISO 8601 as shown in results (UTC), HH:MM:SS, seconds from the start of the "
    "recording ('+12s'), or a phrase such as '10 minutes ago'"
)


def check_time_arg(v: Any) -> Any:
    """A time as given, refused at the door when it is a number no memory time can come from
    (neither Unix seconds up to T_MAX nor an offset from a recording's start): `1e308`,
    `-1e12`, `nan`. Phrases are resolved, and range-checked again, against the memory
    (`ravenmem.timeparse.parse_time`)."""
    if isinstance(v, bool) or not isinstance(v, (int, float, str)):
        return v
    try:
        f = float(v)
    except (ValueError, OverflowError):
        return v
    if not math.isfinite(f):
        raise ValueError(
            "time must be finite" if isinstance(v, float) else f"time {v!r} is not a finite time"
        )
    if not -T_MAX <= f <= T_MAX:
        raise ValueError(f"time {v!r} is out of range ({RANGES['t']})")
    return v


class ToolArgs(BaseModel):
    """Filters every tool takes: a time window."""

    model_config = ConfigDict(extra="forbid")
    after: TimeArg | None = Field(None, description=f"only memories at or after this time ({_TIME_DOC})")
    before: TimeArg | None = Field(None, description="only memories at or before this time")

    @field_validator("after", "before", mode="before")
    @classmethod
    def _time(cls, v: Any) -> Any:
        return check_time_arg(v)


class _Near(ToolArgs):
    near: list[float] | None = Field(
        None, description="[x, y, radius] in metres: only memories taken inside this disc of the map"
    )

    @field_validator("near")
    @classmethod
    def _disc(cls, v: list[float] | None) -> list[float] | None:
        if v is not None and (len(v) != 3 or not all(math.isfinite(c) for c in v) or v[2] <= 0):
            raise ValueError("near must be [x, y, radius] with finite numbers and radius > 0")
        if v is not None:
            Region(*v)  # the map's range (ravenmem.types): a one-line error, not an overflow
        return v

    def disc(self) -> tuple[float, float, float] | None:
        return (self.near[0], self.near[1], self.near[2]) if self.near else None


class _Latest(_Near):
    latest: bool = Field(
        False,
        description="true for questions about the present ('where is it now?', 'is it still "
        "there?'): instead of the best matches, the latest sighting at each place the thing was "
        "seen, newest place first, each with a verdict from the robot's later visits: 'still "
        "there', 'not revisited', 'moved' or 'gone' (the place was looked at again without it), "
        "followed by the later views that no longer show it; k counts places",
    )


class _Diverse(_Latest):
    diverse: bool = Field(
        True,
        description=f"true (the default): one result per moment and place (a view within "
        f"{SAME_VIEW.seconds:g} s, {SAME_VIEW.metres:g} m and {SAME_VIEW.degrees:g} degrees of a better one is left "
        "out), so the results show different views; false: the k best matches, near-duplicates "
        "included (exactly k when the memory holds k)",
    )


class TextArgs(_Diverse):
    query: str = Field(
        ...,
        min_length=1,
        max_length=1000,
        description="what to look for, e.g. 'a red backpack', or words written on a sign",
    )

    @field_validator("query")
    @classmethod
    def _words(cls, v: str) -> str:
        if not v.strip():
            raise ValueError("the query is blank")
        return v


class ImageArgs(_Diverse):
    memory_id: Annotated[int, BeforeValidator(check_id)] | None = Field(  # names an id past SQLite's INTEGER
        None,
        json_schema_extra={"minimum": 0, "maximum": MAX_ID},
        description="search with the image of this memory ('more views like memory 12'); "
        "leave out to search with the image attached to the question",
    )


class TimeArgs(ToolArgs):
    time: TimeArg = Field(..., description=f"where to start: {_TIME_DOC}")

    @field_validator("time", mode="before")
    @classmethod
    def _finite(cls, v: Any) -> Any:
        return check_time_arg(v)


class PositionArgs(ToolArgs):
    # positions within the map's range (ravenmem.types): 1e308 is a one-line error, not an overflow
    x: float = Field(..., ge=-MAX_COORD, le=MAX_COORD, allow_inf_nan=False, description="map x in metres")
    y: float = Field(..., ge=-MAX_COORD, le=MAX_COORD, allow_inf_nan=False, description="map y in metres")
    z: float | None = Field(
        None,
        ge=-MAX_COORD,
        le=MAX_COORD,
        allow_inf_nan=False,
        description="height in metres; planar distance when left out",
    )
    radius: float | None = Field(
        None, gt=0, le=4 * MAX_COORD, allow_inf_nan=False, description="only memories within this many metres"
    )


Runner = Callable[..., list[Hit]]
_CENTRED = "List the memories around a given time (about half before it, half from it on)."
_NEAREST = "List the memories nearest in time to a given time, before or after it."


@dataclass(frozen=True)
class Tool:
    """One retrieval tool: its name, what it is for, its arguments and how it runs."""

    name: str
    key: str
    summary: str
    args: type[ToolArgs]
    order: Order
    metric: Literal["score", "distance"] | None
    _run: Callable[..., list[Hit]]

    def validate(self, raw: Mapping[str, Any] | ToolArgs) -> ToolArgs:
        """Arguments as a checked model; a one-line `InputError` naming the field otherwise."""
        if isinstance(raw, self.args):
            return raw
        try:
            return self.args.model_validate(dict(raw))
        except ValidationError as e:
            err = e.errors()[0]
            where = ".".join(str(p) for p in err["loc"]) or "arguments"
            raise InputError(f"{self.name}: {where}: {err['msg']}") from None
        except (TypeError, ValueError) as e:
            raise InputError(f"{self.name}: arguments must be an object ({e})") from None

    def run(
        self,
        mem: MemoryLike,
        args: ToolArgs | Mapping[str, Any],
        k: int,
        *,
        image: np.ndarray | None = None,
        time_mode: TimeMode = "forward",
        text_search: Runner | None = None,
    ) -> list[Hit]:
        """Run the tool on a memory; results in the tool's `order`.

        `image` is the picture attached to a question (the image tool uses it when no
        `memory_id` is given); `time_mode` picks the time tool's window; `text_search`
        replaces the memory's text search (the caption baseline searches captions). The text
        and image tools' `diverse` argument (ravenmem.memory.diversity) is one of `args`.
        """
        a = self.validate(args)
        return self._run(mem, a, check_k(k), image=image, time_mode=time_mode, text_search=text_search)

    def order_for(self, args: ToolArgs, time_mode: TimeMode = "forward") -> str:
        """The order of this call's results: the latest mode lists places newest first, the time
        tool in its nearest mode nearest in time first."""
        if self.name == "search_time" and time_mode == "nearest":
            return NEAREST_ORDER
        return LATEST_ORDER if getattr(args, "latest", False) else self.order

    def label(self, args: ToolArgs) -> str:
        """How a call is shown to a person or a model, e.g. `search_text("red mug")`."""
        shown = {k: v for k, v in args.model_dump(exclude_defaults=True).items() if v is not None}
        inner = ", ".join(f"{k}={v!r}" for k, v in shown.items())
        return f"{self.name}({inner})"

    def description(
        self, k: int | None = None, *, scores: bool = True, time_mode: TimeMode = "forward"
    ) -> str:
        """What the tool does, for a model or a person. `scores=False` leaves out the similarity
        score / distance (an ablation hides them from the model); `time_mode="centred"` describes
        the time tool's window around the given time instead of from it onwards."""
        modes = {"centred": _CENTRED, "nearest": _NEAREST}
        summary = modes.get(time_mode, self.summary) if self.name == "search_time" else self.summary
        order = NEAREST_ORDER if self.name == "search_time" and time_mode == "nearest" else self.order
        more = f" Returns up to {k} memories" if k else " Returns memories"
        metric = {"score": " with a similarity score (higher is better)", "distance": " with the distance"}
        shown = metric.get(self.metric or "", "") if scores else ""
        return f"{summary}{more}, {order}, each with its id, time and pose{shown}."

    def json_schema(self) -> dict[str, Any]:
        """The full JSON schema of the arguments (MCP and OpenAPI take it as it is)."""
        return self.args.model_json_schema()

    def plain_schema(self) -> dict[str, Any]:
        """The arguments as a plain JSON schema: no anyOf, null or $ref, which every
        OpenAI-compatible server accepts (Gemini's included); `validate` does the checking."""
        full = self.json_schema()
        props: dict[str, Any] = {}
        for name, prop in full.get("properties", {}).items():
            props[name] = _plain(prop)
        return {"type": "object", "properties": props, "required": list(full.get("required", []))}


def _plain(prop: dict[str, Any]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    options = prop.get("anyOf")
    if options:
        types = [o for o in options if o.get("type") != "null"]
        pick = next((o for o in types if o.get("type") == "string"), types[0])
        out.update(_plain(pick))
    else:
        out["type"] = prop.get("type", "string")
        if "items" in prop:
            out["items"] = {"type": prop["items"].get("type", "number")}
    if "description" in prop:
        out["description"] = prop["description"]
    return out


def _text(mem: MemoryLike, a: ToolArgs, k: int, text_search: Runner | None = None, **_: Any) -> list[Hit]:
    assert isinstance(a, TextArgs)
    if text_search is not None:
        return text_search(a.query, k=k, after=a.after, before=a.before, near=a.disc())
    return mem.search_text(a.query, k=k, after=a.after, before=a.before, near=a.disc(), diverse=a.diverse)


def _image(mem: MemoryLike, a: ToolArgs, k: int, image: np.ndarray | None = None, **_: Any) -> list[Hit]:
    assert isinstance(a, ImageArgs)
    if a.memory_id is None and image is None:
        raise InputError("search_image: give memory_id (no image is attached to this question)")
    query = None if a.memory_id is not None else image
    return mem.search_image(
        query, k=k, after=a.after, before=a.before, near=a.disc(), memory_id=a.memory_id, diverse=a.diverse
    )


def _or_latest(search: Runner) -> Runner:
    """The text or image tool, or with `latest=true` its latest mode (`ravenmem.memory.changes`):
    per place the last sighting and the later views without the thing, as `ChangeHit`s."""

    def run(mem: MemoryLike, a: ToolArgs, k: int, image: np.ndarray | None = None, **kw: Any) -> list[Hit]:
        if not getattr(a, "latest", False):
            return search(mem, a, k, image=image, **kw)
        return _latest(mem, a, k, image, kw.get("text_search"))

    return run


def _latest(
    mem: MemoryLike, a: ToolArgs, k: int, image: np.ndarray | None, text_search: Runner | None
) -> list[Hit]:
    name = "search_text" if isinstance(a, TextArgs) else "search_image"
    if text_search is not None:
        raise InputError(f"{name}: latest=true needs the memory's own embeddings (not available here)")
    near = a.disc() if isinstance(a, _Near) else None
    if isinstance(a, TextArgs):
        found = mem.last_seen(a.query, after=a.after, before=a.before, near=near)
    else:
        assert isinstance(a, ImageArgs)
        if a.memory_id is None and image is None:
            raise InputError("search_image: give memory_id (no image is attached to this question)")
        pick = {"memory_id": a.memory_id} if a.memory_id is not None else {"image": image}
        found = mem.last_seen(after=a.after, before=a.before, near=near, **pick)
    return list(found.hits(k))


def _time(mem: MemoryLike, a: ToolArgs, k: int, time_mode: TimeMode = "forward", **_: Any) -> list[Hit]:
    """forward: the k memories from the time on; centred: the k around it; both chronological.
    nearest: the k nearest in time either side (among the 2k around it), nearest first."""
    assert isinstance(a, TimeArgs)
    if time_mode == "nearest":
        t0 = mem.parse_time(a.time)
        around = mem.search_time(a.time, k=min(2 * k, MAX_K), after=a.after, before=a.before, centred=True)
        return sorted(around, key=lambda h: (abs(h.memory.t - t0), h.memory.t, h.memory.id))[:k]
    hits = mem.search_time(a.time, k=k, after=a.after, before=a.before, centred=time_mode == "centred")
    return sorted(hits, key=lambda h: (h.memory.t, h.memory.id))


def _position(mem: MemoryLike, a: ToolArgs, k: int, **_: Any) -> list[Hit]:
    assert isinstance(a, PositionArgs)
    return mem.search_position(a.x, a.y, a.z, k=k, radius=a.radius, after=a.after, before=a.before)


TOOLS: dict[str, Tool] = {
    t.name: t
    for t in (
        Tool(
            "search_text",
            "text",
            "Find memories whose image matches a text description (and text read in the scene).",
            TextArgs,
            "best first",
            "score",
            _or_latest(_text),
        ),
        Tool(
            "search_image",
            "image",
            "Find memories that look like a picture: a memory given by its id, or the image "
            "attached to the question.",
            ImageArgs,
            "best first",
            "score",
            _or_latest(_image),
        ),
        Tool(
            "search_time",
            "time",
            "List the memories from a given time onwards.",
            TimeArgs,
            "chronological",
            None,
            _time,
        ),
        Tool(
            "search_position",
            "position",
            "List the memories taken nearest to a map position (metres).",
            PositionArgs,
            "nearest first",
            "distance",
            _position,
        ),
    )
}
BY_KEY: dict[str, Tool] = {t.key: t for t in TOOLS.values()}


def get_tool(name: str) -> Tool:
    """A tool by name (`search_text`) or key (`text`)."""
    tool = TOOLS.get(name) or BY_KEY.get(name)
    if tool is None:
        raise InputError(f"unknown tool {name!r}; choose one of: {', '.join(TOOLS)}")
    return tool


def hit_json(
    hit: Hit, rank: int, t0: float, image: Callable[[MemoryRecord], str | None] | None = None
) -> dict[str, Any]:
    """A hit as plain data: the one shape that `--json`, the HTTP API and MCP return.

    Times are Unix seconds (`t`), ISO UTC (`time`) and seconds from the first memory
    (`offset_s`); yaw is radians (`yaw`) and degrees (`yaw_deg`); `image` is whatever the
    front end uses to reach the picture (a file path for the CLI, a URL for the service).
    Hits of the latest mode add `change`: the place, its verdict and the evidence
    (`ravenmem.memory.changes.Place.as_dict`, with `role` "sighting" or "revisit").
    A hit that stands for several memories merged by `ravenmem consolidate` also has `count`
    (how many) and `first_t`/`last_t`/`first_time`/`last_time` (when they were seen).
    `supported` (text searches): whether the hit's support reaches above what things that are
    not in the memory reach, the rule `ask --offline` declines by (`ravenmem.agent.support`);
    null where it was not judged (the other tools).
    """
    r = hit.memory
    out = {
        "rank": rank,
        "id": r.id,
        "score": hit.score,
        "distance": hit.distance,
        "t": r.t,
        "time": fmt_time(r.t),
        "offset_s": round(r.t - t0, 3),
        "x": r.pose.x,
        "y": r.pose.y,
        "z": r.pose.z,
        "yaw": r.pose.yaw,
        "yaw_deg": round(math.degrees(r.pose.yaw), 2),
        "image": image(r) if image is not None else r.image_path,
        "source": r.source,
        "frame_index": r.frame_index,
        "ocr_text": r.ocr_text,
        "ocr_match": hit.ocr_match,
        "supported": hit.supported,
        **({"change": change} if (change := getattr(hit, "change", None)) else {}),
    }
    if hit.count > 1 and hit.span is not None:
        first, last = hit.span
        out |= {
            "count": hit.count,
            "first_t": first,
            "last_t": last,
            "first_time": fmt_time(first),
            "last_time": fmt_time(last),
        }
    return out
