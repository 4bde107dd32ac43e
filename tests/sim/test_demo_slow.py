"""The full `ravenmem demo` (ViZDoom + the offline embedder): minutes, so behind `-m slow`."""

import json
import math

import pytest

pytest.importorskip("vizdoom")


@pytest.mark.slow
def test_full_demo(tmp_path) -> None:
    from ravenmem.demo import DemoConfig, run_demo

    png = tmp_path / "demo_map.png"
    rep = run_demo(DemoConfig(out=str(tmp_path / "demo.mem"), png=str(png)))
    assert rep.explore.steps >= 1000 and rep.coverage is not None and rep.coverage > 0.3
    assert rep.memories > 50 and png.stat().st_size > 50_000
    assert 1 <= len(rep.results) <= 8
    for r in rep.results:
        assert r.success == (r.found and r.final_dist <= rep.success_radius)
        if r.found:
            assert math.isfinite(r.answer_dist)
    assert 0.0 <= rep.sr <= 1.0 and "random memory (expected)" in rep.baselines
    saved = json.loads((tmp_path / "demo.mem" / "demo.json").read_text())
    assert saved["memories"] == rep.memories
    assert (tmp_path / "demo.mem" / "map.npz").is_file()
