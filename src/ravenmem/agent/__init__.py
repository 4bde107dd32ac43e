"""Reasoning over the memory: the VLM agent loop, the offline reasoner and the baselines.

from ravenmem.agent import Agent, VLMConfig, create_method
agent = Agent(mem, vlm=VLMConfig(base_url="http://localhost:8000/v1", model="Qwen/Qwen2.5-VL-7B-Instruct"))
answer = agent.ask("Where did I leave the red backpack?")
navqa = create_method("raven", mem, preset="navqa", vlm=...)   # the paper's per-benchmark settings
"""

from __future__ import annotations

from ..memory.protocol import MemoryLike
from .base import METHODS, Method
from .baselines import EmbedderOnly, RandomBaseline, VLMOnly
from .captions import CaptionAgent, CaptionIndex, caption_memories
from .client import VLMClient, VLMError
from .config import VLMConfig
from .loop import Agent
from .methods import create_method
from .offline import OfflineReasoner, OfflineReasonerConfig
from .presets import PRESETS, Preset, get_preset, parse_top_k
from .schema import Answer, Cost, Evidence, QuestionType

__all__ = [
    "METHODS",
    "Agent",
    "Answer",
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
