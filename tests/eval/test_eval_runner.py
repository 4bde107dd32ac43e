from __future__ import annotations

import json
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from ravenmem.agent.schema import Answer, Evidence
from ravenmem.errors import InputError
from ravenmem.eval.config import DatasetConfig, RunConfig
from ravenmem.eval.runner import (
    AnswerLog,
    Runner,
    agent_takes,
    check_methods,
    method_names,
    preset_notes,
    read_rows,
)
from tests.eval.eval_helpers import CountingColorEmbedder, no_vlm_env, run_cfg, write_raven_video


class ColourLookup:
    """A deterministic method: text-search the named colour, answer with the best memory's pose."""

    def __init__(self, name: str, memory: Any, seed: int = 0, **_: Any) -> None:
        self.name, self.memory, self.seed = name, memory, seed

    def ask(self, question: str, image: np.ndarray | None = None) -> Answer:
        (hit,) = self.memory.search_text(question, k=1)
        r = hit.memory
        return Answer(
            question=question,
            method=self.name,
            question_type="position",
            position=list(r.pose.xyz),
            position_source="evidence",
            evidence=[Evidence(id=r.id, t=r.t, x=r.pose.x, y=r.pose.y)],
        )


def cfg(
    root: Path, tmp: Path, methods: list[str] | None = None, limit: int | None = None, **kw: Any
) -> RunConfig:
    return run_cfg(f"raven-qa:{root}", methods or ["lookup"], tmp, dataset_opts={"limit": limit}, **kw)


def make(c: RunConfig, emb: CountingColorEmbedder, factory: Any = None) -> Runner:
    return Runner(
        c,
        method_factory=factory or (lambda n, m, **o: ColourLookup(n, m, **o)),
        embedder=emb,
        log=lambda _: None,
    )


def test_rows_summary_resume_and_cache(
    raven_root: Path, tmp_path: Path, embedder: CountingColorEmbedder
) -> None:
    c = cfg(raven_root, tmp_path, seeds=2, limit=3)
    s1 = make(c, embedder).run()
    run = tmp_path / "run"
    rows = [json.loads(line) for line in (run / "answers.jsonl").read_text().splitlines()]
    assert len(rows) == 6 and {r["seed"] for r in rows} == {0, 1}
    r0 = next(r for r in rows if r["question"]["text"].startswith("Where did you see the blue"))
    assert r0["answer"]["position"] == [4.0, 0.0, 0.0] and r0["score"]["correct"]
    assert r0["truth"]["files"] == ["frame_005.jpg"] and r0["memory"]["memories"] == 10
    assert r0["score"]["frame_correct"] and r0["pred"]["files"] == ["frame_005.jpg"]
    assert json.loads((run / "config.json").read_text())["dataset"] == c.dataset.spec
    assert s1["groups"][0]["accuracy"]["mean"] == 1.0 and s1["groups"][0]["accuracy"]["seeds"] == 2
    assert json.loads((run / "summary.json").read_text())["groups"][0]["rows"] == 6
    embedded = embedder.images
    assert embedded == 10
    # same run again: nothing to do, nothing re-embedded, rows not duplicated; then the rest of the questions
    make(c, embedder).run()
    assert len((run / "answers.jsonl").read_text().splitlines()) == 6 and embedder.images == embedded
    c.dataset.limit = None
    make(c, embedder).run()
    assert len(read_rows(run)) == 8 and embedder.images == embedded
    # another run folder, same memory settings: the cached memory is reused; other keyframes: vectors reused
    make(cfg(raven_root, tmp_path, out="run2"), embedder).run()
    assert embedder.images == embedded
    make(cfg(raven_root, tmp_path, out="run3", keyframes="stride=2"), embedder).run()
    assert embedder.images == embedded
    r3 = read_rows(tmp_path / "run3")
    assert r3[0]["memory"]["memories"] == 5


def test_refuses_other_settings_in_same_folder(
    raven_root: Path, tmp_path: Path, embedder: CountingColorEmbedder
) -> None:
    make(cfg(raven_root, tmp_path, limit=1), embedder).run()
    with pytest.raises(InputError, match="other settings .*keyframes"):
        make(cfg(raven_root, tmp_path, keyframes="stride=3"), embedder).run()


def test_torn_last_line_is_dropped_and_redone(
    raven_root: Path, tmp_path: Path, embedder: CountingColorEmbedder
) -> None:
    make(cfg(raven_root, tmp_path), embedder).run()
    path = tmp_path / "run" / "answers.jsonl"
    lines = path.read_text().splitlines(keepends=True)
    path.write_text("".join(lines[:-1]) + lines[-1][:40])  # a crash in the middle of the last write
    assert len(AnswerLog(path).rows()) == 3
    make(cfg(raven_root, tmp_path), embedder).run()
    assert len(read_rows(tmp_path / "run")) == 4
    assert all(line.endswith("\n") for line in path.read_text().splitlines(keepends=True))


def test_bounded_parallelism_and_failures(
    raven_root: Path, tmp_path: Path, embedder: CountingColorEmbedder
) -> None:
    active, peak, lock = [0], [0], threading.Lock()
    calls: list[str] = []

    class Slow(ColourLookup):
        def ask(self, question: str, image: np.ndarray | None = None) -> Answer:
            with lock:
                active[0] += 1
                peak[0] = max(peak[0], active[0])
                calls.append(question)
            time.sleep(0.05)
            with lock:
                active[0] -= 1
            if "yellow" in question and self.name == "flaky":
                raise RuntimeError("model fell over")
            return super().ask(question, image)

    write_raven_video(raven_root / "vid_b")
    c = cfg(raven_root, tmp_path, methods=["slow", "flaky"], workers=3)
    s = make(c, embedder, lambda n, m, **o: Slow(n, m, **o)).run()
    assert peak[0] == 3  # 8 questions per episode and method, never more than 3 at once
    rows = read_rows(tmp_path / "run")
    failed = [r for r in rows if r["answer"]["failed"]]
    assert len(rows) == 16 and len(failed) == 2
    assert (
        failed[0]["answer"]["error"] == "RuntimeError: model fell over"
        and failed[0]["score"]["correct"] is False
    )
    assert {g["method"]: g["failed"] for g in s["groups"]} == {"flaky": 2, "slow": 0}
    n = len(calls)
    make(
        cfg(raven_root, tmp_path, methods=["slow", "flaky"], workers=3, retry_failed=True),
        embedder,
        lambda n, m, **o: Slow(n, m, **o),
    ).run()
    assert len(calls) == n + 2 and len(read_rows(tmp_path / "run")) == 16


def test_real_methods_through_the_runner(
    raven_root: Path, tmp_path: Path, embedder: CountingColorEmbedder
) -> None:
    c = cfg(raven_root, tmp_path, methods=["embedder-only", "random", "offline"], seeds=2)
    r = Runner(c, embedder=embedder, log=lambda _: None)
    s = r.run()
    g = {x["method"]: x for x in s["groups"]}
    assert set(g) == {"embedder-only", "random", "offline"}
    assert g["embedder-only"]["accuracy"]["mean"] == 1.0  # colours are exactly findable
    rows = read_rows(tmp_path / "run")
    rnd = sorted((r["qid"], r["seed"], r["answer"]["position"]) for r in rows if r["method"] == "random")
    # random is reproducible: a second run folder gives the same answers
    Runner(
        cfg(raven_root, tmp_path, methods=["random"], seeds=2, out="again"),
        embedder=embedder,
        log=lambda _: None,
    ).run()
    again = sorted((r["qid"], r["seed"], r["answer"]["position"]) for r in read_rows(tmp_path / "again"))
    assert rnd == again
    assert all(r["answer"]["cost"]["memories_total"] == 10 for r in rows if r["method"] == "embedder-only")


def test_methods_needing_a_vlm_stop_before_any_question(
    raven_root: Path, tmp_path: Path, embedder: CountingColorEmbedder, monkeypatch: pytest.MonkeyPatch
) -> None:
    for k, v in no_vlm_env(tmp_path).items():
        monkeypatch.setenv(k, v)
    from ravenmem.agent.base import needs_vlm

    assert [m for m in method_names() if needs_vlm(m)] == ["caption", "raven", "vlm-only"]
    for methods in (["raven"], ["offline", "caption"], ["vlm-only"]):
        c = cfg(raven_root, tmp_path, methods=methods)
        with pytest.raises(InputError, match=f"--method {methods[-1]} needs a VLM and none is configured"):
            Runner(c, embedder=embedder, log=lambda _: None).run()
    assert not (tmp_path / "run" / "answers.jsonl").exists() and embedder.images == 0


def test_rows_record_what_ran_and_options_reach_methods(
    raven_root: Path, tmp_path: Path, embedder: CountingColorEmbedder
) -> None:
    seen: list[dict[str, Any]] = []

    def factory(name: str, memory: Any, **opts: Any) -> ColourLookup:
        seen.append(opts)
        return ColourLookup(name, memory, **opts)

    opts = {
        "top_k": {"time": 200, "text": 30},
        "max_tool_calls": 15,
        "preset": "findingdory",
        "temperature": 0.2,
    }
    opts |= {"show_scores": False, "time_mode": "centred"}
    c = cfg(raven_root, tmp_path, methods=["lookup"], method_opts=opts, seeds=2)
    make(c, embedder, factory).run()
    assert {o["seed"] for o in seen} == {0, 1} and all(o == opts | {"seed": o["seed"]} for o in seen)
    rows = read_rows(tmp_path / "run")
    assert {json.dumps(r["ran"], sort_keys=True) for r in rows} == {
        json.dumps({"embedder": "test-color-eval", "method": "lookup", "model": None}, sort_keys=True)
    }
    doc = json.loads((tmp_path / "run" / "config.json").read_text())
    assert doc["method_opts"] == opts and doc["config"]["methods"]["preset"] == "findingdory"
    # a run folder written before the typed configs (flat config.json) resumes, and refuses other settings
    old = {
        k: doc[k]
        for k in (
            "dataset",
            "queries",
            "embedder",
            "vlm",
            "vlm_base_url",
            "keyframes",
            "ocr",
            "thumb_size",
            "method_opts",
            "dataset_opts",
        )
    } | {"methods": ["lookup"], "seeds": 2}
    (tmp_path / "run" / "config.json").write_text(json.dumps(old))
    make(c, embedder, factory).run()
    assert len(read_rows(tmp_path / "run")) == 8
    with pytest.raises(InputError, match=r"other settings \(method_opts\)"):
        make(
            cfg(raven_root, tmp_path, methods=["lookup"], method_opts={"preset": "navqa"}), embedder, factory
        ).run()


def test_unknown_methods_and_options_the_agent_lacks(raven_root: Path, tmp_path: Path) -> None:
    with pytest.raises(
        InputError, match="--method: unknown oracle; choose from caption, embedder-only, offline"
    ):
        check_methods(cfg(raven_root, tmp_path, methods=["oracle"]))
    for option, value in (
        ("show_scores", False),
        ("time_mode", "centred"),
        ("preset", "navqa"),
        ("temperature", 0.5),
    ):
        c = cfg(raven_root, tmp_path, methods=["raven"], method_opts={option: value})
        if agent_takes(option):
            check_methods(c)
        else:  # never silently dropped by an agent that does not know it yet
            with pytest.raises(InputError, match=f"this version's raven method does not take {option}"):
                check_methods(c)
    check_methods(cfg(raven_root, tmp_path, methods=["offline"], method_opts={"show_scores": False}))
    with pytest.raises(InputError, match="--time-mode: one of forward, centred, nearest"):
        cfg(raven_root, tmp_path, method_opts={"time_mode": "backward"})
    with pytest.raises(
        InputError, match="--preset: one of raven-qa-human, raven-qa-robot, raven-qa-robot-open, navqa"
    ):
        cfg(raven_root, tmp_path, method_opts={"preset": "paper"})
    with pytest.raises(InputError, match="--preset raven-qa: the paper's table has one per kind of video"):
        cfg(raven_root, tmp_path, method_opts={"preset": "raven-qa"})
    with pytest.raises(InputError, match="--top-k"):
        cfg(raven_root, tmp_path, method_opts={"top_k": 0})
    with pytest.raises(InputError, match="expected NAME:PATH"):
        DatasetConfig("raven-qa")


def test_a_preset_setting_the_agent_cannot_take_is_said(raven_root: Path, tmp_path: Path) -> None:
    """The paper's presets ask for exactly k memories (diverse=False); an agent version that has
    no such option yet is told so in the run's log instead of dropping it silently."""
    c = cfg(raven_root, tmp_path, methods=["raven"], method_opts={"preset": "navqa"})
    expected = (
        []
        if agent_takes("diverse")
        else ["preset navqa: diverse=False not applied (this version's raven agent takes no 'diverse')"]
    )
    assert preset_notes(c) == expected
    assert preset_notes(cfg(raven_root, tmp_path, methods=["offline"], method_opts={"preset": "navqa"})) == []


def test_run_options_are_the_typed_configs_fields() -> None:
    """Every option of the typed config is a command-line option (one declaration, no table)."""
    from ravenmem.cli.eval import option_fields
    from ravenmem.eval.config import SECTIONS, build_run_config, options_of

    declared = {f.metadata["flag"].split()[0] for cls in SECTIONS.values() for f in options_of(cls)}
    declared |= {f.metadata["flag"].split()[0] for f in options_of(RunConfig)}
    assert {f.metadata["flag"].split()[0] for _, _, f in option_fields()} == declared
    assert {"--pos-threshold", "--scoring", "--caption-encoder", "--time-mode", "--top-k"} <= declared
    c = build_run_config(
        {
            "dataset": "raven-qa:/d",
            "method": "raven, offline",
            "top_k": "time=9",
            "time_threshold": 1.5,
            "pos_threshold": "irs=1",
        }
    )
    assert c.methods.names == ["raven", "offline"] and c.methods.top_k == {"time": 9}
    assert c.thresholds.time_s == 90.0 and c.thresholds.position_m == {"irs": 1.0} and c.seeds == 1
    again = build_run_config({"seeds": 3}, base=c)  # over a recorded run's settings
    assert again.seeds == 3 and again.methods.top_k == {"time": 9} and again.dataset.spec == "raven-qa:/d"
    with pytest.raises(InputError, match="--dataset NAME:PATH is required"):
        build_run_config({"method": "offline"})
