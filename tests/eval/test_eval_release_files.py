"""`ravenmem eval` on folders laid out file for file as the releases ship them (issue 28): no
--tz to guess, the ReMEmbR layout from its package root and from data/navqa, and FindingDory
multi-goal answers in every form a release's prompt asks for."""

from __future__ import annotations

import csv
import json
from pathlib import Path
from typing import Any

import pytest

from tests.agent.scripted_server import ScriptedModel
from tests.cli.helpers import ForkedCli, assert_one_line_error
from tests.eval.eval_helpers import plugin_site, rm
from tests.eval.release_files import (
    QUESTIONS,
    SLIP,
    findingdory_forms_policy,
    ids,
    write_findingdory_release,
    write_raven_release,
    write_remembr_release,
)

EMB = ["--embedder", "test-color-eval", "--thumb-size", "32", "--workers", "1"]
SLIP_ID = ids([*QUESTIONS, SLIP])[-1]


def _eval(cli: ForkedCli, dataset: str, out: Path, site: Path, *extra: str) -> tuple[dict[str, Any], str]:
    """A random-method run, forked by the test process's driver (`ForkedCli`: the whole command
    in its own process; the refusal and FindingDory's run below start their own interpreter)."""
    r = cli(
        "eval",
        "--dataset",
        dataset,
        "--method",
        "random",
        *EMB,
        "--out",
        str(out),
        "--json",
        *extra,
        paths=(site,),
    )
    assert r.returncode == 0, r.stderr
    (g,) = json.loads(r.stdout)["groups"]
    return g, " ".join(r.stderr.split())  # the messages as read, whatever the terminal's width


def test_cli_navqa_zone_is_read_from_the_data(tmp_path: Path, forked_cli: ForkedCli) -> None:
    site = plugin_site(tmp_path)
    remembr = write_remembr_release(tmp_path / "remembr")
    raven = write_raven_release(tmp_path / "RAVEN")
    for root, zone in ((remembr, "UTC-8"), (raven, "UTC-5")):
        g, err = _eval(forked_cli, f"navqa:{root}", tmp_path / f"run{zone}", site)
        # printed: which zone, and from how many rows (6 timed rows; the slip fits no zone)
        assert f"NaVQA data.csv clock times: {zone} (inferred from the data: {zone} puts 5 of 6 " in err
        assert [qid for qid, _ in g["truth_errors"]] == [SLIP_ID]  # every other truth inside its clip
        assert g["accuracy"]["questions"] == len(QUESTIONS)
    # --tz still overrides: ReMEmbR's file read as UTC-5 puts every clock time 3 h off its clip
    g, err = _eval(forked_cli, f"navqa:{remembr}", tmp_path / "forced", site, "--tz", "UTC-5")
    assert "clock times: UTC-5 (--tz)" in err
    errs = dict(g["truth_errors"])
    assert len(errs) == 6 and all(e.endswith("UTC-8 would fit") for q, e in errs.items() if q != SLIP_ID)


def test_cli_navqa_refuses_data_that_disagrees_with_itself(tmp_path: Path, forked_cli: ForkedCli) -> None:
    site = plugin_site(tmp_path)
    pkg = write_remembr_release(tmp_path / "remembr", slip=False)
    table = pkg / "data" / "navqa" / "data.csv"
    remembr_rows = list(csv.reader(table.open(encoding="utf-8")))
    write_raven_release(tmp_path / "RAVEN", slip=False)
    raven_rows = list(
        csv.reader((tmp_path / "RAVEN" / "data_vlm" / "navqa" / "data.csv").open(encoding="utf-8"))
    )
    mixed = remembr_rows[:4] + raven_rows[4:]  # 2 timed rows on ReMEmbR's clock, 3 on RAVEN's
    with open(table, "w", newline="", encoding="utf-8") as f:
        csv.writer(f).writerows(mixed)
    r = rm(
        "eval",
        "--dataset",
        f"navqa:{pkg}",
        "--method",
        "random",
        *EMB,
        "--out",
        str(tmp_path / "r"),
        site=site,
    )
    line = " ".join(assert_one_line_error(r).split())
    assert (
        f"{table}: the data disagrees with itself about its time zone (of 5 timed rows, these fit their "
        "clips under each offset: UTC-5: 3, UTC-8: 2): give --tz" in line
    )
    g, _ = _eval(forked_cli, f"navqa:{pkg}", tmp_path / "given", site, "--tz", "UTC-8")
    assert len(g["truth_errors"]) == 3  # the rows on RAVEN's clock, each named


def test_cli_remembr_layout_loads_from_every_documented_folder(tmp_path: Path, forked_cli: ForkedCli) -> None:
    site = plugin_site(tmp_path)
    pkg = write_remembr_release(tmp_path / "remembr")
    keys = []
    for k, path in enumerate((tmp_path / "remembr", pkg, pkg / "data" / "navqa")):
        g, err = _eval(forked_cli, f"navqa:{path}", tmp_path / f"run{k}", site)
        assert "no frames" not in err and "UTC-8 (inferred" in err
        rows = [json.loads(x) for x in (tmp_path / f"run{k}" / "answers.jsonl").read_text().splitlines()]
        assert len(rows) == len(QUESTIONS) + 1 and all(r["memory"]["memories"] > 0 for r in rows)
        keys.append(sorted((r["qid"], r["memory"]["memories"]) for r in rows))
    assert keys[0] == keys[1] == keys[2]  # the same clips, the same frames, whichever folder
    raven = write_raven_release(tmp_path / "RAVEN")
    g, err = _eval(forked_cli, f"navqa:{raven / 'data_vlm' / 'navqa'}", tmp_path / "raven", site)
    assert "UTC-5 (inferred" in err and g["accuracy"]["questions"] == len(QUESTIONS)


def test_cli_findingdory_goals_in_every_release_form(tmp_path: Path) -> None:
    pytest.importorskip("av")
    pytest.importorskip("pyarrow")
    root = write_findingdory_release(tmp_path / "findingdory")
    site = plugin_site(tmp_path)
    run = tmp_path / "run"
    with ScriptedModel(default=findingdory_forms_policy) as srv:
        r = rm(
            "eval",
            "--dataset",
            f"findingdory:{root}",
            "--method",
            "raven",
            "--vlm",
            "scripted",
            "--vlm-base-url",
            srv.base_url,
            *EMB,
            "--out",
            str(run),
            "--json",
            site=site,
        )
    assert r.returncode == 0, r.stderr
    rows = [json.loads(x) for x in (run / "answers.jsonl").read_text().splitlines()]
    got = {
        r["question"]["text"].split(" yesterday")[0]: (
            r["pred"]["goal_form"],
            r["score"]["correct"],
            [round(g[0] - r["truth"]["goal_times"][0][0]) for g in r["pred"]["goal_times"]],
        )
        for r in rows
    }
    assert got == {
        # RAVEN's prompt: "time": "06:00:00 06:02:10", split on spaces, each goal in its own frames
        "Revisit all the receptacles you placed objects on": ("time field", True, [0, 130]),
        # FindingDory's prompt: "frame_indices": [9, 0] (the second receptacle first, as asked)
        "Revisit all the objects you interacted with": ("frame_indices field", True, [0, -130]),
        # our line, its second goal at 06:00:30 (frame 2): the first goal right is not enough
        "Revisit all the receptacles you picked objects from": ("Goal times line", False, [0, 30]),
        "Navigate to the receptacle that you interacted with at 06:01:00": ("time field", True, [2]),
    }
    raven = next(r for r in rows if r["pred"]["goal_form"] == "time field")
    assert raven["reply"]["time"] == "06:00:00 06:02:10"  # the model's own field, kept in the row
