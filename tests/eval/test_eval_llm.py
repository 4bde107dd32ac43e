"""The LLM judge and the `raven` agent through the runner, against a scripted model over real HTTP."""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from ravenmem.agent.schema import Answer
from ravenmem.eval.config import RunConfig
from ravenmem.eval.judge import parse_verdict
from ravenmem.eval.runner import Runner, read_rows, rejudge
from tests.agent.scripted_server import ScriptedModel, answer, content, tool
from tests.eval.eval_helpers import COLORS, CountingColorEmbedder, run_cfg, write_navqa


def judge_reply(body: dict[str, Any]) -> dict[str, Any]:
    user = next(m["content"] for m in body["messages"] if m["role"] == "user")
    cand = user.split("Candidate answer:", 1)[1]
    return content(json.dumps({"correct": "red" in cand.lower(), "reason": "compared colours"}))


class Speaker:
    """Answers text questions with a fixed sentence (and nothing else)."""

    def __init__(self, name: str, memory: Any, **_: Any) -> None:
        self.name = name

    def ask(self, question: str, image: np.ndarray | None = None) -> Answer:
        return Answer(
            question=question,
            method=self.name,
            question_type="text",
            text="The wall was red." if self.name == "good" else "It was green.",
        )


def navqa_cfg(tmp: Path, **kw: Any) -> RunConfig:
    root = tmp / "navqa"
    if not root.exists():
        write_navqa(root)
    return run_cfg(
        f"navqa:{root}", ["good", "bad"], tmp, dataset_opts={"episodes": "*@1673884500.000-*"}, **kw
    )


def text_acc(g: dict[str, Any]) -> float | None:
    return g["by"]["type"]["text"]["accuracy"]["mean"]


def test_judge_scores_text_answers(tmp_path: Path) -> None:
    with ScriptedModel(default=judge_reply) as srv:
        cfg = navqa_cfg(tmp_path, judge="scripted-judge", judge_base_url=srv.base_url)
        s = Runner(
            cfg,
            method_factory=lambda n, m, **o: Speaker(n, m),
            embedder=CountingColorEmbedder(),
            log=lambda _: None,
        ).run()
        assert len(srv.requests) == 2 and srv.requests[0]["model"] == "scripted-judge"
        assert "Reference answer(s):\n- It was red" in srv.requests[0]["messages"][1]["content"]
    g = {x["method"]: x for x in s["groups"]}
    assert text_acc(g["good"]) == 1.0 and text_acc(g["bad"]) == 0.0
    assert g["good"]["not_judged"] == 0
    text_rows = [r for r in read_rows(tmp_path / "run") if r["question"]["type"] == "text"]
    assert {r["judge"]["reason"] for r in text_rows} == {"compared colours"}


def test_without_judge_text_is_not_scored_then_rejudged(tmp_path: Path) -> None:
    cfg = navqa_cfg(tmp_path)
    s = Runner(
        cfg,
        method_factory=lambda n, m, **o: Speaker(n, m),
        embedder=CountingColorEmbedder(),
        log=lambda _: None,
    ).run()
    g = {x["method"]: x for x in s["groups"]}
    assert g["good"]["not_judged"] == 1 and text_acc(g["good"]) is None
    from ravenmem.agent.config import VLMConfig
    from ravenmem.eval.judge import Judge

    with ScriptedModel(default=judge_reply) as srv:
        n = rejudge(tmp_path / "run", Judge(VLMConfig(base_url=srv.base_url, model="j", backoff=0.0)))
    assert n == 2
    summary = json.loads((tmp_path / "run" / "summary.json").read_text())
    g = {x["method"]: x for x in summary["groups"]}
    assert text_acc(g["good"]) == 1.0 and g["good"]["not_judged"] == 0


def test_verdict_parsing() -> None:
    assert parse_verdict('```json\n{"correct": false, "reason": "no"}\n```').correct is False  # type: ignore[union-attr]
    assert parse_verdict("Yes, it matches.").correct is True  # type: ignore[union-attr]
    assert parse_verdict("I cannot tell") is None


def vlm_reply(body: dict[str, Any]) -> dict[str, Any]:
    """Search the colour the question names, then answer with the best-scoring memory shown."""
    tool_msgs = [m for m in body["messages"] if m["role"] == "tool"]
    if not tool_msgs:
        texts = []
        for m in body["messages"]:
            if m["role"] == "user":
                c = m["content"]
                texts += (
                    [c] if isinstance(c, str) else [p.get("text", "") for p in c if p.get("type") == "text"]
                )
        colour = next(w for w in re.findall(r"[a-z]+", " ".join(texts).lower()) if w in COLORS)
        return tool("search_text", query=colour)
    best = max(
        re.findall(r"^\[m(\d+)\].*score ([\d.]+)", tool_msgs[-1]["content"], re.M), key=lambda x: float(x[1])
    )
    return answer(question_type="position", answer="there", evidence=[int(best[0])])


def test_raven_agent_through_the_runner(scoring_root: Path, tmp_path: Path) -> None:
    with ScriptedModel(default=vlm_reply) as srv:
        cfg = run_cfg(
            f"raven-qa:{scoring_root / 'sim' / 'simple'}",
            ["raven"],
            tmp_path,
            vlm="scripted",
            vlm_base_url=srv.base_url,
            method_opts={"top_k": 3, "max_tool_calls": 2},
        )
        s = Runner(cfg, embedder=CountingColorEmbedder(), log=lambda _: None).run()
        assert len(srv.requests) == 6  # two requests per question
    (g,) = s["groups"]
    assert g["vlm"] == "scripted" and g["accuracy"]["mean"] == 1.0 == g["frame_accuracy"]["mean"]
    assert g["position_accuracy"]["mean"] == 1.0 and g["pos_error_m"]["mean"] == 0.0
    assert g["images_per_q"]["mean"] == 3 and g["tokens_per_q"]["mean"] > 0
    assert g["alpha"]["mean"] == 3 / 40  # 3 of 40 memories shown
    rows = read_rows(tmp_path / "run")
    assert all(r["answer"]["position_source"] == "evidence" and r["vlm"] == "scripted" for r in rows)
    assert all(
        r["ran"] == {"method": "raven", "model": "scripted", "embedder": "test-color-eval"} for r in rows
    )


def test_top_k_study_against_the_scripted_model(scoring_root: Path, tmp_path: Path) -> None:
    """A study end to end: the raven agent over real HTTP, once per k; the model sees k memories."""
    from ravenmem.eval.studies import option_study

    with ScriptedModel(default=vlm_reply) as srv:
        base = run_cfg(
            f"raven-qa:{scoring_root / 'sim' / 'simple'}",
            ["raven"],
            tmp_path,
            vlm="scripted",
            vlm_base_url=srv.base_url,
            method_opts={"max_tool_calls": 2},
        )
        doc = option_study(
            base, "top-k", [1, 4], tmp_path / "topk", embedder=CountingColorEmbedder(), log=lambda _: None
        )
        tool_results = [m["content"] for b in srv.requests for m in b["messages"] if m["role"] == "tool"]
    assert len(srv.requests) == 12  # 3 questions x 2 settings x (search, answer)
    shown = sorted(len(re.findall(r"^\[m\d+\]", c, re.M)) for c in tool_results)
    assert shown == [1, 1, 1, 4, 4, 4]
    pts = {p["value"]: p for p in doc["points"]}
    assert pts[1]["alpha"]["mean"] == pytest.approx(1 / 40) and pts[4]["alpha"]["mean"] == pytest.approx(
        4 / 40
    )
    assert pts[1]["images_per_q"]["mean"] == 1 and pts[4]["images_per_q"]["mean"] == 4
    assert pts[1]["frame_accuracy"]["mean"] == 1.0 == pts[4]["frame_accuracy"]["mean"]
    assert pts[4]["tokens_per_q"]["mean"] > pts[1]["tokens_per_q"]["mean"]


def first_shown_reply(body: dict[str, Any]) -> dict[str, Any]:
    """Search the colour the question names, then answer with the first memory listed (best ranked)."""
    tool_msgs = [m for m in body["messages"] if m["role"] == "tool"]
    if not tool_msgs:
        return vlm_reply(body)
    first = re.search(r"^\[m(\d+)\]", tool_msgs[-1]["content"], re.M)
    return answer(question_type="position", answer="there", evidence=[int(first.group(1))] if first else [])


def test_scores_study_with_a_preset_against_the_scripted_model(scoring_root: Path, tmp_path: Path) -> None:
    """The scores ablation end to end: what the model reads with scores shown and hidden, the
    preset's k and temperature, the run's seed, and what each row says ran."""
    from ravenmem.eval.studies import option_study

    with ScriptedModel(default=first_shown_reply) as srv:
        base = run_cfg(
            f"raven-qa:{scoring_root / 'sim' / 'simple'}",
            ["raven"],
            tmp_path,
            vlm="scripted",
            vlm_base_url=srv.base_url,
            method_opts={"preset": "raven-qa-human"},
            seeds=2,
        )
        doc = option_study(
            base,
            "scores",
            [True, False],
            tmp_path / "scores",
            embedder=CountingColorEmbedder(),
            log=lambda _: None,
        )
        requests = list(srv.requests)
    assert len(requests) == 2 * 3 * 2 * 2  # settings x questions x seeds x (search, answer)
    assert {b["temperature"] for b in requests} == {0.0001} and {b.get("seed") for b in requests} == {0, 1}
    tool_texts = [m["content"] for b in requests for m in b["messages"] if m["role"] == "tool"]
    assert all(len(re.findall(r"^\[m\d+\]", t, re.M)) == 5 for t in tool_texts)  # the preset's k
    with_scores = [t for t in tool_texts if "score " in t]
    assert len(with_scores) == len(tool_texts) // 2  # shown in one setting, hidden in the other
    pts = {p["value"]: p for p in doc["points"]}
    assert pts[True]["frame_accuracy"]["mean"] == 1.0 == pts[False]["frame_accuracy"]["mean"]
    rows = read_rows(tmp_path / "scores")
    assert {r["variant"] for r in rows} == {"show_scores=on", "show_scores=off"}
    assert {(r["ran"]["method"], r["ran"]["model"], r["answer"]["preset"]) for r in rows} == {
        ("raven", "scripted", "raven-qa-human")
    }
