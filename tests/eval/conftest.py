"""Fixtures for the evaluation tests (helpers live in eval_helpers.py, a unique module name)."""

from __future__ import annotations

from tests.eval.eval_helpers import embedder, raven_root, scoring_root  # noqa: F401 - pytest fixtures
