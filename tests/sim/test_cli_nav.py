import json
import math
from dataclasses import replace

import pytest
import typer
from typer.testing import CliRunner

from ravenmem.cli.nav import register
from ravenmem.errors import InputError


def _app() -> typer.Typer:
    app = typer.Typer()
    register(app)

    @app.command("version")
    def _version() -> None:  # a second command keeps typer in multi-command mode
        typer.echo("x")

    return app


def test_explore_then_navigate_by_text_and_by_position(tmp_path) -> None:
    app, runner = _app(), CliRunner()
    mem = tmp_path / "rooms.mem"
    png = tmp_path / "map.png"
    r = runner.invoke(
        app,
        [
            "explore",
            "--env",
            "synthetic:rooms",
            "--memory",
            str(mem),
            "--steps",
            "500",
            "--embedder",
            "test-boxes",
            "--keyframe-dist",
            "1.0",
            "--png",
            str(png),
            "--json",
        ],
    )
    assert r.exit_code == 0, r.output
    out = json.loads(r.stdout)
    assert out["memories"] > 5 and out["coverage"] > 0.8 and png.stat().st_size > 10_000
    assert (mem / "map.npz").is_file() and (mem / "map.json").is_file() and (mem / "explore.json").is_file()

    r = runner.invoke(
        app,
        [
            "navigate",
            "--memory",
            str(mem),
            "--to",
            "blue box",
            "--method",
            "embedder-only",
            "--drive",
            "--json",
        ],
    )
    assert r.exit_code == 0, r.output
    nav = json.loads(r.stdout)
    assert nav["answer"]["found"] and nav["answer"]["method"] == "embedder-only"
    assert nav["ok"] and nav["path_length_m"] > 5.0 and len(nav["waypoints"]) >= 2
    assert nav["pose_stamped"]["header"]["frame_id"] == "map"
    drive = nav["drive"]
    assert drive["reached"] and math.dist(drive["final"], (12.5, 1.5)) < 3.0  # the blue box

    # a position goal plans on the saved map alone: no simulator is started
    r = runner.invoke(app, ["navigate", "--memory", str(mem), "--from", "2,1.5", "--to", "6.0,3.0"])
    assert r.exit_code == 0, r.output
    assert "A* path" in r.stdout and '"frame_id": "map"' in r.stdout

    r = runner.invoke(app, ["map", "--memory", str(mem), "--json"])
    assert r.exit_code == 0, r.output
    counts = json.loads(r.stdout)
    assert counts["kind"] == "explored" and counts["free"] > 1000 and counts["occupied"] > 100


def test_navigate_needs_a_map(tmp_path, box_embedder) -> None:
    import ravenmem

    app, runner = _app(), CliRunner()
    ravenmem.create(tmp_path / "m", embedder=box_embedder, ocr=False).close()
    r = runner.invoke(app, ["navigate", "--memory", str(tmp_path / "m"), "--to", "1,2"])
    assert r.exit_code != 0
    assert "no map.npz" in str(r.exception)


def test_demo_on_the_synthetic_world(tmp_path, box_embedder) -> None:
    from ravenmem.demo import DemoConfig, run_demo

    cfg = DemoConfig(
        maps=["synthetic:rooms"],
        out=str(tmp_path / "demo"),
        steps=600,
        embedder=box_embedder,
        text_method="embedder-only",
        keyframe_dist=1.0,
        keyframe_turn=0.5,
    )
    lines: list[str] = []
    rep = run_demo(cfg, progress=lines.append)
    (run,) = rep.maps
    # every phase says how far it is, of what total, and (once under way) how long is left
    explore = [ln for ln in lines if ln.startswith("explore, control steps: ")]
    assert explore and all("/600 (" in ln and "elapsed" in ln for ln in explore), lines
    assert any(ln.startswith("explore: stopped at control step") for ln in lines), lines
    driven = [ln for ln in lines if ln.startswith("  phase II, answered and driven: ")]
    assert driven[0].startswith("  phase II, answered and driven: 1/12 (8%)") and "ETA" in driven[0], lines
    assert driven[-1].startswith("  phase II, answered and driven: 12/12 (100%)") and "done" in driven[-1]
    assert any(ln.startswith("  image queries, pictures rendered: 3/3") for ln in lines), lines
    assert run.queries == ["red box", "blue box", "green box"]
    # the colour embedder reads the boxes' colours: text finds them; oracle perception too
    assert rep.sr("text") == 1.0 and rep.sr("oracle") == 1.0
    assert all(a.final_dist <= 3.0 and a.path_m > 0 for a in run.of("oracle"))
    # the synthetic world renders a picture of each box from a place no keyframe was taken at;
    # the colour embedder finds each box by its picture (a memory that saw it, within 4 m of it)
    assert sorted(p.name for p in (tmp_path / "demo" / "rooms" / "queries").iterdir()) == [
        "BlueBox.png",
        "GreenBox.png",
        "RedBox.png",
    ]
    assert all(a.found and a.answer_err < 4.0 for a in run.of("image")), run.of("image")
    assert run.random_expected < 0.5 and len(run.of("random")) == 3
    table = rep.table()
    assert "oracle perception" in table and "SR over 1 maps" in table and "red box" in table
    saved = json.loads((tmp_path / "demo" / "demo.json").read_text())
    assert saved["sr"]["oracle"] == 1.0 and saved["labels"]["oracle"] == "oracle perception"
    assert sorted(p.name for p in (tmp_path / "demo").iterdir()) == ["demo.json", "rooms"]
    assert (tmp_path / "demo" / "rooms" / "map.png").stat().st_size > 20_000
    # a second run leaves the first one's results alone and writes the next free folder (a short
    # one: where it writes is what is checked, not what it finds)
    again: list[str] = []
    rep2 = run_demo(replace(cfg, steps=60), progress=again.append)
    assert rep2.out == str(tmp_path / "demo-2") and (tmp_path / "demo-2" / "demo.json").is_file()
    assert (
        again[0]
        == f"{tmp_path / 'demo'} already exists (an earlier run's results stay there); this run writes {tmp_path / 'demo-2'} (--overwrite replaces {tmp_path / 'demo'})"
    )
    assert json.loads((tmp_path / "demo" / "demo.json").read_text()) == saved
    assert f"outputs in {tmp_path / 'demo-2'}/" in rep2.table()
    # --overwrite replaces a demo's own folder only
    (tmp_path / "mine").mkdir()
    (tmp_path / "mine" / "notes.txt").write_text("keep")
    with pytest.raises(InputError, match="was not written by the demo"):
        run_demo(replace(cfg, out=str(tmp_path / "mine"), overwrite=True))
    assert (tmp_path / "mine" / "notes.txt").read_text() == "keep"
