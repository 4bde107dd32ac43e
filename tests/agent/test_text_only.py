"""Text-only models: `vision = false`, or a server that refuses pictures (once, then text): each
memory goes to the model as text (time, pose, score, OCR text, labels of its picture from the
memory's own embedder), and the answer records that the model saw no pictures."""

from __future__ import annotations

import re

import pytest

from ravenmem.agent import Agent
from ravenmem.agent.labels import FrameLabels
from tests.agent.conftest import SCENE, config_for
from tests.agent.scripted_server import ScriptedModel, answer, tool


def ids_by_index(mem) -> dict[int, int]:
    return {r.frame_index: r.id for r in mem.all_records()}


def label_lines(text: str) -> dict[int, str]:
    return {int(m[1]): m[2] for m in re.finditer(r"^\[m(\d+)\].*picture shows \(labels\): (.*)$", text, re.M)}


def test_vision_false_sends_text_with_labels_and_no_pictures(mem):
    ids = ids_by_index(mem)
    script = [tool("search_text", query="red"), answer(question_type="position", evidence=[ids[1]])]
    with ScriptedModel(script) as srv:
        ans = Agent(mem, vlm=config_for(srv, vision=False)).ask("Where is the red ball?")
        assert srv.images(0) == srv.images(1) == 0
        tool_text = next(m["content"] for m in srv.requests[1]["messages"] if m["role"] == "tool")
        system = srv.requests[0]["messages"][0]["content"]
    assert "camera images described in words" in system
    lines = label_lines(tool_text)
    red = {ids[i] for i, (c, _, _) in enumerate(SCENE) if c == "red"}
    assert red <= set(lines)  # both red memories were shown, as text
    for mid in red:  # the colour embedder puts a red frame next to the vocabulary's red things
        assert all("red" in w.lower() for w in lines[mid].split(", ")), lines[mid]
    assert "time 2023-11-14" in tool_text and "pose x=" in tool_text and "score" in tool_text
    assert "image attached" not in tool_text
    assert not ans.failed and ans.vision is False and ans.cost.images == 0
    assert any("the model saw no pictures" in n for n in ans.notes)


@pytest.mark.parametrize("status", [400, 500])
def test_a_server_that_refuses_pictures_gets_text_after_one_retry(mem, status):
    ids = ids_by_index(mem)
    script = [
        tool("search_text", query="red"),
        answer(question_type="position", evidence=[ids[8]]),
        tool("search_text", query="red"),
        answer(question_type="position", evidence=[ids[8]]),
    ]
    with ScriptedModel(script, reject_images=status) as srv:
        agent = Agent(mem, vlm=config_for(srv, max_retries=1))
        ans = agent.ask("Where is the red ball?")
        refused = [i for i, r in enumerate(srv.responses) if r.get("status") == status]
        # 400: refused at once; 500 (llama.cpp's server): only after every retry repeats it
        assert len(refused) == (1 if status == 400 else 2)
        retry = srv.requests[refused[-1] + 1]
        assert srv.images(refused[-1] + 1) == 0
        text = "\n".join(
            p["text"] if isinstance(p, dict) else p
            for m in retry["messages"]
            for p in (m["content"] if isinstance(m["content"], list) else [m["content"]])
            if p
        )
        assert f"[m{ids[8]}]" in text and "picture shows (labels):" in text  # the refused pictures, as labels
        n = len(srv.requests)
        again = agent.ask("Where is the red ball?")  # sticky: the next question sends no picture at all
        assert all(srv.images(i) == 0 for i in range(n, len(srv.requests)))
    assert not ans.failed and ans.vision is False and [e.id for e in ans.evidence] == [ids[8]]
    assert any("the server refused pictures" in n and str(status) in n for n in ans.notes)
    assert not again.failed and again.vision is False


def test_a_model_with_vision_is_never_switched(mem):
    ids = ids_by_index(mem)
    with ScriptedModel([tool("search_text", query="red")], reject_images=400) as srv:
        ans = Agent(mem, vlm=config_for(srv, vision=True)).ask("Where is the red ball?")
    assert ans.failed and "HTTP 400: this model does not take images" in (ans.error or "")
    assert ans.vision is True
    del ids


def test_labels_come_from_the_stored_vectors(mem):
    recs = mem.all_records()
    words = FrameLabels(mem, vocabulary=["red apple", "blue sky", "green leaf"], k=1)(recs)
    colours = {r.id: c for r, (c, _, _) in zip(recs, SCENE)}
    for rid, (w,) in words.items():
        if colours[rid] in ("red", "blue", "green"):
            assert w.split()[0] == colours[rid]
