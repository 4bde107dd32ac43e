"""The answer every method returns, shared with the evaluation, the service and the CLI.

Units: positions in metres in the map frame, `yaw` in radians (counter-clockwise from the map
x axis, as in `Pose`), times in Unix seconds (UTC), durations in seconds.
"""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, Field, model_validator

from ..types import MemoryRecord

QuestionType = Literal["position", "time", "binary", "text", "duration"]
Source = Literal["model", "evidence", "none"]
# why a question failed, typed (the HTTP status and a robot's reason come from it, never from the
# wording of `error`): its time ran out, the model could not be reached or kept failing, or it
# answered nothing usable within its turns
Failure = Literal["out_of_time", "model_failed", "no_answer"]


class Evidence(BaseModel):
    """A memory the answer rests on, as shown to the user (time, pose, score, image)."""

    id: int
    t: float
    x: float
    y: float
    z: float = 0.0
    yaw: float = 0.0
    score: float | None = None
    image_path: str | None = None

    @classmethod
    def of(cls, rec: MemoryRecord, score: float | None = None) -> Evidence:
        """A stored memory as evidence (its time, pose and picture), with the score it got."""
        p = rec.pose
        return cls(id=rec.id, t=rec.t, x=p.x, y=p.y, z=p.z, yaw=p.yaw, score=score, image_path=rec.image_path)


class Cost(BaseModel):
    """Retrieval cost per question (the paper's alpha = distinct memories shown / memories stored)."""

    memories_shown: int = 0
    memories_total: int = 0
    alpha: float = 0.0
    images: int = 0
    image_bytes: int = 0
    prompt_tokens: int = 0
    completion_tokens: int = 0
    tool_calls: int = 0
    tool_calls_rejected: int = Field(
        default=0, description="tool calls not run, each with a named reason in the trace"
    )
    wall_s: float = 0.0


class PlaceChange(BaseModel):
    """What the memory knows about a place where the thing was seen (`ravenmem.memory.changes`): when
    it was last seen there, whether the robot looked at the place again later without it, and
    the verdict. `status` is the thing's own ("gone" when even its newest place, or a view of
    it on the same pass, was looked at again without it)."""

    query: str = ""
    place: int
    verdict: Literal["still there", "moved", "gone", "not revisited"]
    status: Literal["still there", "moved", "gone", "not revisited"] | None = None
    x: float
    y: float
    z: float = 0.0
    sightings: int = 0
    first_seen: float
    last_seen: float = Field(description="Unix seconds of the last sighting at this place")
    last_seen_id: int
    revisited: float | None = Field(default=None, description="first later view of the place without it")
    revisit_ids: list[int] = Field(default_factory=list)
    moved_to: int | None = Field(default=None, description="the place it was seen at since (moved)")
    seen_since: float | None = None
    seen_since_id: int | None = None
    text: str = ""


class Answer(BaseModel):
    question: str = ""
    method: str = Field(default="", description="the method that actually ran: raven, offline, vlm-only, ...")
    model: str | None = Field(default=None, description="the VLM's model name, None for model-free methods")
    model_host: str | None = Field(
        default=None, description="host[:port] of the VLM endpoint (never the key)"
    )
    embedder: str | None = Field(
        default=None, description="the embedder (or caption text encoder) used to retrieve"
    )
    preset: str | None = Field(default=None, description="the preset the settings came from, if any")
    question_type: QuestionType = "text"
    text: str = ""
    position: list[float] | None = Field(default=None, description="[x, y, z] in the map frame, metres")
    yaw: float | None = Field(default=None, description="heading in radians, map frame")
    frame_id: str | None = Field(
        default=None, description="the frame (REP 105) position and yaw are in: the memory's, map or odom"
    )
    map_id: str | None = Field(default=None, description="the identity of the map the position is in")
    position_source: Source = "none"
    yaw_source: Source = "none"
    time: float | None = Field(default=None, description="Unix seconds (UTC)")
    duration: float | None = Field(default=None, description="seconds")
    yes: bool | None = None
    found: bool = True
    failed: bool = False
    error: str | None = None
    failure: Failure | None = Field(
        default=None, description="why it failed: out_of_time | model_failed | no_answer (None: it did not)"
    )
    unsupported: bool = Field(
        default=False,
        description="the position is farther than the support threshold from every memory the "
        "model was shown: an invented place, which nothing drives to unless the user allows it",
    )
    support_distance: float | None = Field(
        default=None, description="metres from the position to the nearest memory the model was shown"
    )
    vision: bool | None = Field(
        default=None,
        description="whether the model was shown pictures (False: a text-only model, memories "
        "described as text); None for methods without a model",
    )
    evidence: list[Evidence] = Field(default_factory=list)
    reasoning: str = ""
    notes: list[str] = Field(
        default_factory=list,
        description="every fallback, correction or warning applied to the model's answer, and why",
    )
    cost: Cost = Field(default_factory=Cost)
    changes: list[PlaceChange] = Field(
        default_factory=list,
        description="for questions about the present: the places the thing was seen at, newest "
        "first, with what later visits showed (still there, not revisited, moved, gone)",
    )

    @model_validator(mode="after")
    def _failure_kind(self) -> Answer:
        """A failed answer always says why (a caller that gave no kind: the model failed); an
        answer that did not fail has none."""
        if self.failed and self.failure is None:
            self.failure = "model_failed"
        elif not self.failed:
            self.failure = None
        return self
