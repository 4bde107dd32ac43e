"""The benchmarks as their releases lay them out and score them (issue 20): layouts, time zones,
scoring rules, multi-goal answers, and runs that replay to the same numbers."""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from ravenmem.agent.schema import Answer
from ravenmem.errors import InputError
from ravenmem.eval.answer_forms import parse_goal_times
from ravenmem.eval.config import Thresholds
from ravenmem.eval.datasets import load_dataset
from ravenmem.eval.datasets.findingdory import INSTRUCTIONS, normalise_question
from ravenmem.eval.datasets.frames import BASE_DAY
from ravenmem.eval.metrics import bootstrap_ci, score_row, seed_accuracy
from ravenmem.eval.runner import build_row
from ravenmem.eval.types import Episode, Question, Truth
from tests.agent.scripted_server import ScriptedModel
from tests.cli.helpers import ForkedCli
from tests.eval.eval_helpers import no_vlm_env, plugin_site, rm
from tests.eval.release_layouts import (
    NAV_QUESTIONS,
    NAV_T0,
    findingdory_policy,
    navqa_policy,
    write_findingdory_goals,
    write_raven_navqa,
    write_raven_qa_release,
    write_remembr_navqa,
)

EMB = ["--embedder", "test-color-eval", "--thumb-size", "32", "--workers", "1"]


def ep_of(times: list[float], files: list[str] | None = None) -> Episode:
    return Episode(
        id="ep",
        dataset="t",
        key="k",
        frames=lambda: [],
        questions=[],
        frame_times=times,
        frame_files=files or [],
    )


# ------------------------------------------------------------------------------------ scoring bugs
def test_a_no_and_a_zero_survive_the_row() -> None:
    t = Truth(yes=False, duration=0.0, pos_tol=0.0)
    assert Truth.from_dict(t.to_dict()) == t  # every field, False and 0 included
    ep = ep_of([1000.0, 1001.0])
    no = Question(id="q", text="Did you see a purple car?", type="binary", truth=Truth(yes=False))
    row = build_row(ep, no, "m", 0, Answer(yes=False), Thresholds())
    assert row["truth"]["yes"] is False and row["score"]["correct"] is True  # a correct "No"
    assert build_row(ep, no, "m", 0, Answer(yes=True), Thresholds())["score"]["correct"] is False
    still = Question(id="d", text="How long did you stand still?", type="duration", truth=Truth(duration=0.0))
    assert build_row(ep, still, "m", 0, Answer(duration=5.0), Thresholds())["score"]["correct"] is True
    assert build_row(ep, still, "m", 0, Answer(duration=90.0), Thresholds())["score"]["correct"] is False
    # an answer's heading stays in radians, as Answer.yaw (and ROS) has it
    assert build_row(ep, no, "m", 0, Answer(yes=False, yaw=3.14), Thresholds())["pred"]["yaw"] == 3.14


def test_bootstrap_interval_is_fixed_by_the_rows() -> None:
    rows = [{"qid": f"q{i}", "seed": 0, "score": {"correct": i < 6}} for i in range(20)]
    acc = seed_accuracy(rows)
    assert acc["mean"] == 0.3 and acc["questions"] == 20
    lo, hi = acc["ci"]
    assert 0.05 <= lo < 0.3 < hi <= 0.55 and seed_accuracy(rows)["ci"] == [lo, hi]  # same rows, same interval
    assert bootstrap_ci(np.ones((5, 2))) == (1.0, 1.0)
    assert seed_accuracy(rows[:2])["ci"] == [1.0, 1.0]  # two right answers: no spread to resample


# ------------------------------------------------------------------------------------ NaVQA
def test_navqa_raven_repository_layout(tmp_path: Path) -> None:
    repo = write_raven_navqa(tmp_path / "RAVEN")
    for path in (repo / "data_vlm", repo):  # the repository's data folder, or the repository
        eps = load_dataset(f"navqa:{path}")
        assert len(eps) == len(NAV_QUESTIONS)  # a clip per question, each its own episode
    q = {x.id: (e, x) for e in eps for x in e.questions}
    ep, pos = q["SHORT_pos"]
    assert pos.truth.positions == [[28.0, 0.0, 0.0]] and ep.frame_times[0] == NAV_T0 + 5
    assert q["SHORT_no"][1].truth.yes is False and q["MEDIUM_time"][1].horizon == "medium"
    # the zone is the data's own: 3 of the 4 clock times fit UTC-5 (LONG_late is before its clip)
    assert "UTC-5 (inferred from the data: UTC-5 puts 3 of 4 data.csv truth times" in ep.meta["zone"]
    assert ep.meta["notes"] == [
        f"sequence(s) 3 have no frames ({repo.parent / 'RAVEN'}/coda_data/<seq>/ or frames/<seq>/poses.csv): "
        "their 2 question(s) are left out"
    ]
    late = q["LONG_late"][1]
    assert late.meta["truth_error"].startswith("truth time 10:55:02 (UTC-5) is 8 s before it starts")


def test_navqa_truths_read_in_the_release_zone_and_never_clamped(tmp_path: Path) -> None:
    repo = write_raven_navqa(tmp_path / "RAVEN")
    shutil.rmtree(repo / "data_vlm" / "questions")  # only data.csv and the clips: truths from data.csv
    q = {x.id: x for e in load_dataset(f"navqa:{repo}") for x in e.questions}
    # 10:55:28 in the RAVEN release's UTC-5 is 1 s before the recording ends: that frame's pose
    assert q["SHORT_pos"].truth.positions == [[28.0, 0.0, 0.0]] and not q["SHORT_pos"].meta
    assert q["MEDIUM_time"].truth.times == [NAV_T0 + 15]
    wrong = {x.id: x for e in load_dataset(f"navqa:{repo}", tz="America/Chicago") for x in e.questions}
    err = wrong["SHORT_pos"].meta["truth_error"]
    assert "10:55:28 (America/Chicago) is 3599 s after it ends" in err and err.endswith("UTC-5 would fit")
    assert wrong["SHORT_pos"].truth.positions == []  # not the last pose: no position at all
    with pytest.raises(InputError, match="--tz: unknown time zone 'Mars/Olympus'"):
        load_dataset(f"navqa:{repo}", tz="Mars/Olympus")


def test_navqa_remembr_clips_are_episodes_in_utc_minus_8(tmp_path: Path) -> None:
    repo = write_remembr_navqa(tmp_path / "remembr")
    for path in (repo, repo / "remembr", repo / "remembr" / "data"):
        eps = load_dataset(f"navqa:{path}")
        assert len(eps) == len(NAV_QUESTIONS), path
    windows = {
        x.id: (e.frame_times[0] - NAV_T0, e.frame_times[-1] - NAV_T0) for e in eps for x in e.questions
    }
    assert windows == {qid: (float(w[0]), float(w[1])) for qid, _, _, w, *_ in NAV_QUESTIONS}
    q = {x.id: x for e in eps for x in e.questions}
    assert q["SHORT_pos"].truth.positions == [[28.0, 0.0, 0.0]] and q["SHORT_no"].truth.yes is False
    assert "UTC-8 (inferred from the data: UTC-8 puts 3 of 4" in eps[0].meta["zone"]
    utc5 = {x.id: x for e in load_dataset(f"navqa:{repo}", tz="UTC-5") for x in e.questions}
    assert utc5["SHORT_pos"].meta["truth_error"].endswith("UTC-8 would fit")


def test_navqa_without_any_frames_is_one_line(tmp_path: Path) -> None:
    repo = write_remembr_navqa(tmp_path / "remembr")
    shutil.rmtree(repo / "remembr" / "coda_data")
    with pytest.raises(InputError, match=r"no sequence has frames \(sequence\(s\) 0 have no frames"):
        load_dataset(f"navqa:{repo}")


# ------------------------------------------------------------------------------------ FindingDory
def test_findingdory_normalisations_and_every_goal_scored(tmp_path: Path) -> None:
    assert normalise_question("The robot's goal is: Go where you were at 8:05, not 09:15:20.") == (
        "Go where you were at 08:05:00, not 09:15:20."
    )
    (ep,) = load_dataset(f"findingdory:{write_findingdory_goals(tmp_path / 'fd')}")
    multi, at, none = ep.questions
    assert (
        multi.text == "Navigate to the red box, then to the blue box." and multi.instructions == INSTRUCTIONS
    )
    assert at.text == "Navigate to what you saw at 06:01:00."
    assert parse_goal_times("I think so. Goal times: 06:00:43 6:09") == [21643.0, 22140.0]

    def score(q: Question, text: str, t: float | None = None) -> bool | None:
        return build_row(ep, q, "m", 0, Answer(text=text, time=t), Thresholds())["score"]["correct"]

    day = BASE_DAY
    assert score(multi, "Goal times: 06:00:00 06:02:10", day + 6 * 3600) is True  # frames 0 and 9
    assert score(multi, "Goal times: 06:00:00", day + 6 * 3600) is False  # one goal of two
    assert score(multi, "Goal times: 06:02:10 06:00:00") is False  # in order
    assert score(at, "Goal times: 06:01:00") is True and score(at, "Goal times: 06:02:00") is False
    assert build_row(ep, none, "m", 0, Answer(found=False), Thresholds())["score"]["correct"] is True


# ------------------------------------------------------------------------------------ RAVEN-QA
def test_raven_qa_release_subsets_splits_and_stamps(tmp_path: Path) -> None:
    eps = {e.id: e for e in load_dataset(f"raven-qa:{write_raven_qa_release(tmp_path / 'data')}")}
    assert sorted(eps) == [
        "habitat_sim/ep_1",
        "irs/simple/indoor/vid_a",
        "irs_hard/hard/vid_b",
        "real_world/walk_1",
    ]
    assert {(q.subset, q.split) for e in eps.values() for q in e.questions} == {
        ("irs", "simple"),
        ("irs_hard", "hard"),
        ("habitat_sim", ""),
        ("real_world", ""),
    }
    irs = eps["irs/simple/indoor/vid_a"]  # its frames are stamped by file name in timestamp_to_position
    assert irs.frame_times[0] == BASE_DAY + 600 and irs.frame_times[11] == BASE_DAY + 611
    assert "timestamp_to_filename" in irs.meta["time_rule"]
    assert [q.truth.times for q in irs.questions] == [
        [BASE_DAY + 603],
        [BASE_DAY + 608],
    ]  # the release's answer times
    assert [q.truth.times for q in eps["real_world/walk_1"].questions] == [
        [],
        [],
    ]  # its answer frames have no stamp


def test_release_scoring_rule_beside_the_papers() -> None:
    ep = ep_of([BASE_DAY + 600 + i for i in range(4)], [f"f{i}.jpg" for i in range(4)])
    q = Question(
        id="q",
        text="Where?",
        type="frame",
        truth=Truth(files=["f2.jpg"], positions=[[6.0, 0.0, 5.0]], times=[BASE_DAY + 602]),
        subset="real_world",
    )
    ans = Answer(time=BASE_DAY + 603.4, position=[6.0, 1.5, 0.0])  # 1.4 s late, 1.5 m off in y, 5 m in z
    row = build_row(ep, q, "m", 0, ans, Thresholds(position_m={"real_world": 2.0}), dataset="raven-qa:/d")
    paper = row["score"]
    assert paper["rule"] == "paper" and paper["correct"] is False  # the nearest frame is f3, not f2
    assert paper["pos_correct"] is False and paper["threshold_m"] == 2.0  # 3-D: 5.2 m
    rel = score_row(row, Thresholds(position_m={"real_world": 2.0}, scoring="release"))
    assert rel["rule"] == "release" and rel["correct"] is True  # within 2 s (whole seconds) of the stamp
    assert rel["pos_correct"] is True and rel["pos_error_m"] == 1.5  # x, y only, under 2 m
    unstamped = build_row(
        ep,
        Question(id="u", text="Where?", type="frame", truth=Truth(files=["f2.jpg"])),
        "m",
        0,
        ans,
        Thresholds(scoring="release"),
        dataset="raven-qa:/d",
    )
    assert (
        unstamped["score"]["correct"] is None and "leaves the question out" in unstamped["score"]["skipped"]
    )
    other = build_row(ep, q, "m", 0, ans, Thresholds(scoring="release"), dataset="navqa:/d")
    assert other["score"]["rule"] == "paper"  # NaVQA's and FindingDory's scorers are the paper's rule


# ------------------------------------------------------------------------------------ through `ravenmem eval`
def _summary(r: Any) -> dict[str, Any]:
    assert r.returncode == 0, r.stderr
    return json.loads(r.stdout)


def raven_on(dataset: str, url: str) -> list[str]:
    """The options that run the raven agent on a dataset against the scripted model at `url`."""
    return ["--dataset", dataset, "--method", "raven", "--vlm", "scripted", "--vlm-base-url", url]


def _group(summary: dict[str, Any]) -> dict[str, Any]:
    (g,) = summary["groups"]
    return g


def test_cli_navqa_raven_repository_scores_records_and_replays(tmp_path: Path, forked_cli: ForkedCli) -> None:
    """Run and report in fresh interpreters; the replays (and the replay's report) forked by one
    driver (`ForkedCli`), each still the whole command."""
    repo = write_raven_navqa(tmp_path / "RAVEN")
    site = plugin_site(tmp_path)
    run = tmp_path / "run"
    with ScriptedModel(default=navqa_policy) as srv:
        args = raven_on(f"navqa:{repo}", srv.base_url)
        g = _group(_summary(rm("eval", *args, *EMB, "--out", str(run), "--json", site=site)))
        asked = len(srv.requests)
    by_type = g["by"]["type"]
    assert by_type["binary"]["accuracy"]["mean"] == 1.0  # the correct "No"
    assert by_type["position"]["accuracy"]["mean"] == 1.0 and by_type["duration"]["accuracy"]["mean"] == 1.0
    assert g["truth_errors"] == [
        ["LONG_late", "truth time 10:55:02 (UTC-5) is 8 s before it starts (recording 10:55:10-10:55:29)"]
    ]
    r = rm("eval", "report", str(run), "--out", str(tmp_path / "a" / "report.md"), site=site)
    assert r.returncode == 0, r.stderr
    report = (tmp_path / "a" / "report.md").read_text()
    assert "Clock times: NaVQA data.csv clock times: UTC-5" in report
    assert "sequence(s) 3 have no frames" in report and "their 2 question(s) are left out" in report
    assert (
        "1 question(s) have a truth outside their recording and are not scored (truth errors): LONG_late"
        in report
    )
    assert "## Per horizon: NaVQA's table" in report and "Pos. acc. ≤ 15 m" in report
    # the manifest and every model exchange are in the run folder
    man = json.loads((run / "manifest.json").read_text())
    assert man["dataset"]["sha256"] and man["dataset"]["questions"] == len(NAV_QUESTIONS)
    assert (
        man["model"] == "scripted"
        and man["scoring"]["rule"] == "paper"
        and man["time_zones"][0].startswith("NaVQA data.csv clock times: UTC-5")
    )
    assert man["ravenmem"] and "git_revision" in man and man["settings"]["methods"]["names"] == ["raven"]
    io = [json.loads(x) for x in (run / "model_io.jsonl").read_text().splitlines()]
    assert len(io) == asked and all(e["response"]["choices"] for e in io)
    keys = {json.loads(x)["key"] for x in (run / "answers.jsonl").read_text().splitlines()}
    assert {e["context"] for e in io} == keys  # each reply labelled with the answer it served
    # replayed with no model anywhere: the same numbers, the same report
    env = no_vlm_env(tmp_path)
    again = _summary(
        forked_cli(
            "eval", "--replay", str(run), "--out", str(tmp_path / "re"), "--json", paths=(site,), env=env
        )
    )
    first = json.loads((run / "summary.json").read_text())
    assert again["groups"] == first["groups"]
    assert (
        forked_cli(
            "eval", "report", str(tmp_path / "re"), "--out", str(tmp_path / "b" / "report.md"), paths=(site,)
        ).returncode
        == 0
    )
    assert (tmp_path / "b" / "report.md").read_text() == report
    r = forked_cli("eval", "--replay", str(run), "--top-k", "9", paths=(site,), env=env)
    assert (
        r.returncode == 2 and "--top-k (None -> 9) changed; those answers need new model replies" in r.stderr
    )
    r = forked_cli("eval", "--replay", str(run), "--embedder", "offline", paths=(site,), env=env)
    assert r.returncode == 2 and "--embedder (test-color-eval -> offline) changed" in r.stderr
    stricter = _group(
        _summary(
            forked_cli(
                "eval", "--replay", str(run), "--pos-threshold", "0.5", "--json", paths=(site,), env=env
            )
        )
    )
    assert stricter["by"]["type"]["position"]["accuracy"]["mean"] < 1.0  # re-scored, no model asked


def test_cli_remembr_clips_and_a_wrong_zone(tmp_path: Path) -> None:
    repo = write_remembr_navqa(tmp_path / "remembr")
    site = plugin_site(tmp_path)
    args = ["--dataset", f"navqa:{repo}", "--method", "embedder-only", *EMB]
    _summary(rm("eval", *args, "--out", str(tmp_path / "run"), "--json", site=site))
    rows = [json.loads(x) for x in (tmp_path / "run" / "answers.jsonl").read_text().splitlines()]
    assert len({r["episode"] for r in rows}) == len(NAV_QUESTIONS)  # a memory per clip
    sizes = {r["qid"]: r["memory"]["memories"] for r in rows}
    assert sizes == {qid: w[1] - w[0] + 1 for qid, _, _, w, *_ in NAV_QUESTIONS}
    g = _group(
        _summary(
            rm("eval", *args, "--tz", "America/Chicago", "--out", str(tmp_path / "cst"), "--json", site=site)
        )
    )
    errs = dict(g["truth_errors"])
    assert "SHORT_pos" in errs and errs["SHORT_pos"].endswith("UTC-8 would fit")
    assert g["by"]["type"]["position"]["accuracy"]["mean"] is None  # no silent position scored instead


def test_cli_findingdory_multi_goal_answers(tmp_path: Path) -> None:
    pytest.importorskip("av")
    root = write_findingdory_goals(tmp_path / "fd")
    site = plugin_site(tmp_path)
    with ScriptedModel(default=findingdory_policy) as srv:
        args = raven_on(f"findingdory:{root}", srv.base_url)
        g = _group(_summary(rm("eval", *args, *EMB, "--out", str(tmp_path / "run"), "--json", site=site)))
        asked = [json.dumps(b["messages"][1]) for b in srv.requests]
    assert g["accuracy"]["mean"] == 1.0 and g["accuracy"]["questions"] == 3  # the two-goal answer included
    assert g["by"]["category"]["multi-goal tasks"]["accuracy"]["mean"] == 1.0
    assert all("The robot's goal is" not in a for a in asked) and any("06:01:00" in a for a in asked)
    assert all("Goal times: HH:MM:SS" in a for a in asked)  # the model is asked for every goal's time


def test_cli_raven_qa_release_layout_thresholds_and_scoring(tmp_path: Path) -> None:
    data = write_raven_qa_release(tmp_path / "data")
    site = plugin_site(tmp_path)
    args = ["--dataset", f"raven-qa:{data}", "--method", "embedder-only", *EMB]
    thr = ["--pos-threshold", "irs=1,irs_hard=2,habitat_sim=1,real_world=2"]
    g = _group(_summary(rm("eval", *args, *thr, "--out", str(tmp_path / "run"), "--json", site=site)))
    by = g["by"]["subset_split"]
    assert set(by) == {"irs/simple", "irs_hard/hard"}
    # the answers are 1.5 m from the frames named: right under 2 m, wrong under 1 m
    assert (
        by["irs/simple"]["position_accuracy"]["mean"] == 0.0
        and by["irs_hard/hard"]["position_accuracy"]["mean"] == 1.0
    )
    subsets = g["by"]["subset"]
    assert (
        subsets["habitat_sim"]["position_accuracy"]["mean"] == 0.0
        and subsets["real_world"]["position_accuracy"]["mean"] == 1.0
    )
    assert g["frame_accuracy"]["mean"] == 1.0  # the paper's target retrieval: the named frame
    r = rm("eval", *args, "--pos-threshold", "irs=1,simple=2", "--out", str(tmp_path / "bad"), site=site)
    assert r.returncode == 2 and "--pos-threshold: no subset named simple in this dataset" in r.stderr
    r = rm(
        "eval",
        "report",
        str(tmp_path / "run"),
        "--scoring",
        "release",
        "--out",
        str(tmp_path / "rel.md"),
        site=site,
    )
    assert r.returncode == 0, r.stderr
    text = (tmp_path / "rel.md").read_text()
    assert (
        "Scoring rule: release" in text
        and "release rule (RAVEN-QA rows): the answer's time within 2 s" in text
    )
    assert (
        "2 question(s) not scored: the release gives no timestamp for this answer's frames" in text
    )  # real_world
