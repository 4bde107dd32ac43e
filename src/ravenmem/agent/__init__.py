"""Reasoning over the memory: the VLM agent loop, the offline reasoner and the baselines."""

from __future__ import annotations

from .schema import Answer, Cost, Evidence, QuestionType

__all__ = ["Answer", "Cost", "Evidence", "QuestionType"]
