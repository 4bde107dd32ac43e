"""Defaults a new user meets, run as the `ravenmem` command: keyframes that sparsify, the ratio
printed, diverse search results, and commands that load only the models they need."""

from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

import pytest

from ravenmem.cli.commands import COMMANDS
from tests.cli.helpers import ForkedCli, run_cli
from tests.conftest import TUM, tum_data

REPO = Path(__file__).resolve().parents[2]


def rm(*args: str, importtime: bool = False) -> subprocess.CompletedProcess[str]:
    return run_cli(*args, timeout=600, python_flags=("-X", "importtime") if importtime else ())


def imported(stderr: str) -> set[str]:
    """Module names from `python -X importtime` output, with the top-level package of each (a
    package whose import failed half-way shows only its submodules' lines)."""
    names = {
        line.rsplit("|", 1)[1].strip() for line in stderr.splitlines() if line.startswith("import time:")
    }
    return names | {n.split(".")[0] for n in names}


@pytest.fixture(scope="module")
def parked(tmp_path_factory) -> Path:
    """The first six TUM frames (0.17 s), all given one pose: one view, as a parked robot sees it."""
    tum_data()
    d = tmp_path_factory.mktemp("parked")
    listed = [
        ln.split() for ln in (TUM / "rgb.txt").read_text().splitlines() if ln and not ln.startswith("#")
    ]
    rows = ["file,t,x,y,z,yaw"]
    for i, (stamp, rel) in enumerate(listed[:6]):
        shutil.copy(TUM / rel, d / f"f{i}.jpg")
        rows.append(f"f{i}.jpg,{stamp},1.0,2.0,0.0,0.5")
    (d / "poses.csv").write_text("\n".join(rows) + "\n")
    return d


@pytest.fixture(scope="module")
def every_frame(parked: Path, tmp_path_factory) -> Path:
    mem = tmp_path_factory.mktemp("all") / "all.mem"
    r = rm("ingest", str(parked), "-m", str(mem), "--keyframes", "all", "--no-ocr", "--json")
    assert r.returncode == 0, r.stderr
    out = json.loads(r.stdout)
    assert out["kept"] == 6 and out["keyframe_ratio"] == 1.0 and out["keyframes"] == "every frame"
    return mem


def test_default_keyframes_keep_one_view_of_a_parked_camera(parked: Path, tmp_path: Path) -> None:
    r = rm("ingest", str(parked), "-m", str(tmp_path / "m.mem"), "--no-ocr")
    assert r.returncode == 0, r.stderr
    assert "6 frames seen, 1 kept, 1 in 6.0" in r.stdout and "skipped 5: keyframe selection" in r.stdout
    assert "keyframe rules: moved 0.5 m or turned 15 deg or 5 s passed" in r.stdout
    assert "x smaller than the raw decoded video" in r.stdout


def test_search_is_diverse_unless_no_diverse(every_frame: Path, forked_cli: ForkedCli) -> None:
    """The searches forked by one driver (`ForkedCli`); the importtime test below runs a text
    search in a fresh interpreter."""

    def rm(*args: str) -> subprocess.CompletedProcess[str]:
        return forked_cli(*args, timeout=600)

    r = rm("search", "-m", str(every_frame), "a computer keyboard", "--json")
    assert r.returncode == 0, r.stderr
    assert len(json.loads(r.stdout)["results"]) == 1  # six frames of one moment and place: one hit
    r = rm("search", "-m", str(every_frame), "a computer keyboard", "--no-diverse", "--json")
    hits = json.loads(r.stdout)["results"]
    assert len(hits) == 5 and max(h["t"] for h in hits) - min(h["t"] for h in hits) < 0.2
    r = rm("search", "-m", str(every_frame), "--like", "1", "-k", "3", "--json")
    assert len(json.loads(r.stdout)["results"]) == 1
    r = rm("search", "-m", str(every_frame), "--like", "1", "-k", "3", "--no-diverse", "--json")
    assert len(json.loads(r.stdout)["results"]) == 3


# the modules of the other commands (ask, eval, serve, nav...) and what only they use
OTHER_COMMANDS = {f"ravenmem.cli.{m}" for m, _ in COMMANDS.values()} | {"ravenmem.eval", "openai", "fastapi"}


def test_commands_load_only_what_they_need(every_frame: Path) -> None:
    seen = {}
    for args in (["info"], ["search", "--time", "+0.1s"]):
        r = rm(*args, "-m", str(every_frame), importtime=True)
        assert r.returncode == 0, r.stderr
        seen[args[0]] = imported(r.stderr)
        assert "torch" not in seen[args[0]], args  # no model at all for these
        assert not OTHER_COMMANDS & seen[args[0]], args  # nor another command's code
    assert "ravenmem.agent" not in seen["info"]  # info asks nothing
    for args in (["--help"], ["search", "--help"], ["info", "-h"]):
        r = rm(*args, importtime=True)
        assert r.returncode == 0 and "Usage: ravenmem" in r.stdout, r.stderr
        assert not OTHER_COMMANDS & imported(r.stderr) and "ravenmem.agent" not in imported(r.stderr), args
    r = rm("ask", "--help", importtime=True)  # a command of another module loads that module only
    mods = imported(r.stderr)
    assert r.returncode == 0 and "--allow-unsupported" in r.stdout, r.stderr
    assert "ravenmem.cli.agent" in mods and not {"ravenmem.cli.eval", "ravenmem.cli.serve"} & mods
    r = rm("search", "-m", str(every_frame), "a computer keyboard", importtime=True)
    assert r.returncode == 0, r.stderr
    mods = imported(r.stderr)
    assert "ravenmem.embed._bert_onnx" in mods  # the text encoder ran ...
    assert not {"torch", "sentence_transformers", "transformers"} & mods  # ... without these
    assert "ravenmem.embed._effnet_onnx" not in mods  # and the image network was never built
    assert "scipy.spatial" not in mods  # the position tool's k-d tree: only when it is asked


@pytest.mark.slow
def test_ingest_default_on_real_tum_sparsifies(tmp_path: Path) -> None:
    """723 frames of a hand-held camera turning over a desk (24 s): ~70 distinct views kept, not 720.

    Slow (every frame is embedded for the novelty rule: 10 s quiet, minutes loaded); what it
    covers is kept in the default suite by the parked-camera test above (the default rules on
    real frames), tests/ingest/test_keyframes.py and test_routes.py (each rule, the novelty rule
    included) and test_tour.py (the default ingest of the shipped sample); the full recording's
    count is measured by benchmarks/bench_ingest.py (docs/measured.md)."""
    tum_data()
    r = rm("ingest", str(TUM), "-m", str(tmp_path / "tum.mem"), "--no-ocr", "--thumb-size", "0", "--json")
    assert r.returncode == 0, r.stderr
    out = json.loads(r.stdout)
    assert out["frames_seen"] == 723 and 60 <= out["kept"] <= 85, out  # 72 measured
    assert out["keyframe_ratio"] == pytest.approx(723 / out["kept"], abs=1e-3)
    assert out["skipped"]["similar to last keyframe"] >= 1  # the novelty rule did its part
    assert out["compression_vs_raw"] > 500


def test_the_command_table_is_what_the_modules_register() -> None:
    """`ravenmem --help` lists the other modules' commands from `cli.commands` without importing
    them: the table names each command's module, in the order of the full command tree, with
    the first paragraph of its help (what the listing shortens)."""
    import typer

    from ravenmem.cli.main import LazyGroup, _extension, every_command

    group = typer.main.get_command(every_command())
    assert isinstance(group, LazyGroup)
    core = ["ingest", "search", "info", "name"]
    assert list(group.commands) == core + list(COMMANDS)  # every command, in the listed order
    for name, (module, text) in COMMANDS.items():
        sub = _extension(module)
        names = [c.name for c in sub.registered_commands] + [g.name for g in sub.registered_groups]
        assert name in names, (name, module)
        first = (group.commands[name].help or "").split("\n\n")[0]
        assert " ".join(text.split()) == " ".join(first.split()), name


def test_unknown_and_misspelt_commands_are_named_as_before() -> None:
    """A misspelt command is suggested from every command, the lazily loaded ones included."""
    r = rm("consolidat")
    line = r.stderr.strip()
    assert r.returncode == 2 and line.startswith("error: No such command 'consolidat'"), r.stderr
    assert "consolidate" in line and "Traceback" not in r.stderr
    r = rm("eval", "stdy")
    assert r.returncode == 2 and "No such command 'stdy'" in r.stderr and "study" in r.stderr
