"""Benchmarks: NaVQA, FindingDory, RAVEN-QA and our own questions, scored the papers' way.

from ravenmem.eval import DatasetConfig, MethodConfig, RunConfig, run, write_report
summary = run(RunConfig(DatasetConfig("raven-qa:/data/RAVEN_QA"), MethodConfig(["offline", "random"])))
write_report(summary["run_dir"], "report.md")
"""

from __future__ import annotations

from typing import Any

from .config import (
    DatasetConfig,
    MemoryConfig,
    MethodConfig,
    ModelConfig,
    OutputConfig,
    RunConfig,
    Thresholds,
)
from .datasets import load_dataset
from .metrics import score_row, summarize
from .runner import Runner, read_rows, run
from .types import Episode, Question, Truth

__all__ = [
    "DatasetConfig",
    "Episode",
    "MemoryConfig",
    "MethodConfig",
    "ModelConfig",
    "OutputConfig",
    "Question",
    "RunConfig",
    "Runner",
    "Thresholds",
    "Truth",
    "load_dataset",
    "read_rows",
    "run",
    "score_row",
    "summarize",
    "write_report",
]


def write_report(run_dir: Any, out: Any, **kw: Any) -> Any:
    """Markdown tables + PNG plots for a run folder (or a folder of runs); see eval.report."""
    from .report import write_report as _wr

    return _wr(run_dir, out, **kw)
