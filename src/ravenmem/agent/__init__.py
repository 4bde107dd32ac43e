"""Reasoning over the memory: the VLM agent loop, the offline reasoner and the baselines.

from ravenmem.agent import AskRequest, MethodOptions, VLMConfig, ask
vlm = VLMConfig(base_url="http://localhost:8000/v1", model="Qwen/Qwen2.5-VL-7B-Instruct")
result = ask(mem, AskRequest("Where did I leave the red backpack?", MethodOptions(vlm=vlm)))
result.answer, result.refusal                   # the answer, and why it must not be used (or None)
navqa = create_method("raven", mem, preset="navqa", vlm=vlm)   # a method, with the paper's settings
"""

from __future__ import annotations

from ..memory.protocol import MemoryLike
from .ask import AskRequest, AskResult, MethodOptions, QuestionFailed, ask, build_method, create_method
from .base import METHODS, Method
from .baselines import EmbedderOnly, RandomBaseline, VLMOnly
from .captions import CaptionAgent, CaptionIndex, caption_memories
from .client import VLMClient, VLMError
from .config import VLMConfig
from .loop import Agent
from .offline import OfflineReasoner, OfflineReasonerConfig
from .presets import PRESETS, Preset, get_preset, parse_top_k
from .schema import Answer, Cost, Evidence, QuestionType

__all__ = [
    "METHODS",
    "Agent",
    "Answer",
    "AskRequest",
    "AskResult",
    "MethodOptions",
    "QuestionFailed",
    "ask",
    "build_method",
    "CaptionAgent",
    "CaptionIndex",
    "Cost",
    "EmbedderOnly",
    "Evidence",
    "MemoryLike",
    "Method",
    "OfflineReasoner",
    "OfflineReasonerConfig",
    "PRESETS",
    "Preset",
    "QuestionType",
    "RandomBaseline",
    "VLMClient",
    "VLMConfig",
    "VLMError",
    "VLMOnly",
    "caption_memories",
    "create_method",
    "get_preset",
    "parse_top_k",
]
