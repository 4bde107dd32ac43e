"""The structured answer every method (VLM agent, offline reasoner, baselines) returns.

One schema for all methods so the evaluation runner can score them the same way. Positions
are never invented: when a model names no coordinates for a position question, the agent fills
them from the best evidence memory and says so in `position_source`.
"""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, Field

QuestionType = Literal["position", "time", "binary", "text", "duration"]


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


class Cost(BaseModel):
    """Retrieval cost per question (the paper's alpha = distinct memories shown / memories stored)."""

    memories_shown: int = 0
    memories_total: int = 0
    alpha: float = 0.0
    images: int = 0
    prompt_tokens: int = 0
    completion_tokens: int = 0
    tool_calls: int = 0
    wall_s: float = 0.0


class Answer(BaseModel):
    question: str = ""
    method: str = ""
    question_type: QuestionType = "text"
    text: str = ""
    position: list[float] | None = Field(default=None, description="[x, y, z] in the map frame, metres")
    yaw: float | None = None
    position_source: Literal["model", "evidence", "none"] = "none"
    time: float | None = Field(default=None, description="Unix seconds (UTC)")
    duration: float | None = Field(default=None, description="seconds")
    yes: bool | None = None
    found: bool = True
    failed: bool = False
    error: str | None = None
    evidence: list[Evidence] = Field(default_factory=list)
    reasoning: str = ""
    cost: Cost = Field(default_factory=Cost)
