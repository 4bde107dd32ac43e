"""The test suite's real data: its path comes from RAVENMEM_TUM_DATA, and a run that requires
the data (RAVENMEM_REQUIRE_DATA=1, as `.ci/run` sets it) fails where it would have skipped."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]


def run_pytest(tmp_path: Path, **env: str) -> subprocess.CompletedProcess[str]:
    test = tmp_path / "test_needs_tum.py"
    test.write_text(
        "from tests.conftest import tum_data\n\n\ndef test_needs_tum():\n    assert (tum_data() / 'rgb.txt').is_file()\n"
    )
    full = {k: v for k, v in os.environ.items() if not k.startswith("RAVENMEM_")}
    full.update(PYTHONPATH=os.pathsep.join([str(REPO / "src"), str(REPO)]), **env)
    return subprocess.run(
        [sys.executable, "-m", "pytest", "-q", "-rs", "-p", "no:cacheprovider", str(test)],
        capture_output=True,
        text=True,
        cwd=tmp_path,
        env=full,
        timeout=120,
    )


def test_missing_data_skips_with_the_variable_to_set(tmp_path: Path) -> None:
    r = run_pytest(tmp_path, RAVENMEM_TUM_DATA=str(tmp_path / "nowhere"))
    assert r.returncode == 0 and "1 skipped" in r.stdout, r.stdout
    assert str(tmp_path / "nowhere") in r.stdout and "RAVENMEM_TUM_DATA" in r.stdout


def test_missing_data_fails_when_required(tmp_path: Path) -> None:
    r = run_pytest(tmp_path, RAVENMEM_TUM_DATA=str(tmp_path / "nowhere"), RAVENMEM_REQUIRE_DATA="1")
    assert r.returncode == 1 and "1 failed" in r.stdout, r.stdout
    assert "RAVENMEM_REQUIRE_DATA=1 but real TUM data not found" in r.stdout


def test_the_variable_points_the_tests_at_a_recording(tmp_path: Path) -> None:
    rec = tmp_path / "elsewhere"
    rec.mkdir()
    (rec / "rgb.txt").write_text("# timestamp filename\n")
    r = run_pytest(tmp_path, RAVENMEM_TUM_DATA=str(rec), RAVENMEM_REQUIRE_DATA="1")
    assert r.returncode == 0 and "1 passed" in r.stdout, r.stdout


def test_ci_requires_the_data() -> None:
    ci = (REPO / ".ci" / "run").read_text()
    assert "export RAVENMEM_REQUIRE_DATA=1" in ci
    assert ci.index("export RAVENMEM_REQUIRE_DATA=1") < ci.index("python -m pytest")
