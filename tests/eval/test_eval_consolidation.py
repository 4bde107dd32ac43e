"""The consolidation study: accuracy against memories kept, consolidated vs thinned in time."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from ravenmem.errors import InputError
from ravenmem.eval.report import write_report
from ravenmem.eval.runner import read_rows
from ravenmem.eval.studies import consolidation_study
from tests.eval.eval_helpers import CountingColorEmbedder, run_cfg

PNG = b"\x89PNG\r\n\x1a\n"
QUIET = {"log": lambda _: None}


def test_consolidation_keeps_what_uniform_thinning_loses(scoring_root: Path, tmp_path: Path) -> None:
    """40 frames, grey but for a red, a green and a blue one (the answers). Consolidated to 7
    memories, the grey runs merge and the three answers survive; thinned uniformly to 7, only
    the green frame (13) happens to be kept."""
    emb = CountingColorEmbedder()
    base = run_cfg(f"raven-qa:{scoring_root / 'sim' / 'simple'}", ["embedder-only"], tmp_path)
    doc = consolidation_study(base, [7], tmp_path / "study", max_distance=math.inf, embedder=emb, **QUIET)
    pts = {(p["strategy"], p["budget"]): p for p in doc["points"]}
    assert set(pts) == {("full", None), ("consolidate", 7), ("uniform", 7)}
    assert pts[("full", None)]["memories"] == 40
    assert pts[("consolidate", 7)]["memories"] == 7 == pts[("uniform", 7)]["memories"]
    assert pts[("full", None)]["accuracy"]["mean"] == 1.0
    assert pts[("consolidate", 7)]["accuracy"]["mean"] == 1.0
    assert pts[("uniform", 7)]["accuracy"]["mean"] == pytest.approx(1 / 3)
    embedded = emb.images
    assert 0 < embedded <= 40  # embedded once (the cache skips repeated images), copied, reduced
    rows = read_rows(tmp_path / "study")
    assert {r["variant"] for r in rows} == {"full", "consolidate=7", "uniform=7"}
    assert {r["memory"]["memories"] for r in rows} == {40, 7}
    # running it again reuses the reduced memories and the answers
    again = consolidation_study(base, [7], tmp_path / "study", max_distance=math.inf, embedder=emb, **QUIET)
    assert emb.images == embedded and len(again["points"]) == 3
    text = write_report(tmp_path / "study", tmp_path / "study" / "report.md").read_text()
    assert "## Consolidation study" in text and "| consolidate 7 | 7 |" in text
    assert (tmp_path / "study" / "report_figs" / "study_consolidation_0.png").read_bytes()[:8] == PNG


def test_consolidation_study_bad_input(scoring_root: Path, tmp_path: Path) -> None:
    base = run_cfg(f"raven-qa:{scoring_root / 'sim' / 'simple'}", ["embedder-only"], tmp_path)
    with pytest.raises(InputError, match="--budgets"):
        consolidation_study(base, [0], tmp_path / "s", embedder=CountingColorEmbedder(), **QUIET)
    with pytest.raises(InputError, match="--strategies"):
        consolidation_study(
            base, [5], tmp_path / "s", strategies=("magic",), embedder=CountingColorEmbedder(), **QUIET
        )
