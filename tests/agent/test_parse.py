"""Reading model replies: JSON extraction, lenient fields, and the evidence rules of build_answer."""

from __future__ import annotations

import time

import pytest
from pydantic import ValidationError

from ravenmem.agent.parse import MAX_DECODE_ATTEMPTS, MAX_REPLY_CHARS, ModelAnswer, build_answer, extract_json
from ravenmem.agent.tool_calls import WorkingMemory
from ravenmem.types import Hit
from tests.agent.conftest import T0


@pytest.mark.parametrize(
    "text, expected",
    [
        ('{"a": 1}', {"a": 1}),
        ('Sure! ```json\n{"a": 2}\n``` hope that helps', {"a": 2}),
        ('The answer is {"a": {"b": [1, 2]}} and {"c": 3}', {"a": {"b": [1, 2]}}),
        ('[{"tool": "search_text", "arguments": {}}]', [{"tool": "search_text", "arguments": {}}]),
        ("no json here", None),
        ("{broken: json", None),
        ("", None),
        (None, None),
        ("__import__('os').system('echo pwned')", None),
    ],
)
def test_extract_json(text, expected):
    assert extract_json(text) == expected


def test_model_answer_is_lenient_about_spelling():
    ma = ModelAnswer.model_validate(
        {
            "question_type": "Location",
            "text": "there",
            "memory_ids": ["m3", "[m4]", 5, {"id": 6}],
            "yes": "no",
            "duration": "1m30s",
            "position": {"x": 1, "y": 2},
            "extra": "ignored",
        }
    )
    assert ma.question_type == "position" and ma.answer == "there" and ma.evidence == [3, 4, 5, 6]
    assert ma.yes is False and ma.duration_s == 90.0 and ma.position == [1.0, 2.0, 0.0]


@pytest.mark.parametrize(
    "bad",
    [
        {"question_type": "vibes"},
        {"evidence": ["the red one"]},
        {"position": [1, 2, 3, 4]},
        {"position": "kitchen"},
        {"duration_s": "a while"},
        {"found": "maybe"},
        {"position": [1.0, float("nan"), 0.0]},
        {"yaw_deg": float("inf")},
        {"yaw_deg": "north"},
    ],
)
def test_model_answer_rejects_wrong_types(bad):
    with pytest.raises(ValidationError):
        ModelAnswer.model_validate(bad)


def test_build_answer_rules(mem):
    recs = mem.all_records()
    wm = WorkingMemory()
    for r, s in ((recs[1], 0.9), (recs[8], 0.95), (recs[3], None)):
        wm.add(Hit(memory=r, score=s), "search_text")
    # no evidence named: the best-scored memory shown, its pose and time
    a = build_answer(ModelAnswer(question_type="position"), "Where?", wm, mem, "raven")
    assert a.evidence[0].id == recs[8].id and a.position == [8.0, 3.0, 0.5] and a.time == T0 + 80
    # a 2-d position takes z from the evidence; a time string is parsed against the memory
    a = build_answer(
        ModelAnswer(evidence=[recs[1].id], position=[1.2, 0.1], time="+15s"), "Where?", wm, mem, "raven"
    )
    assert a.position == [1.2, 0.1, 0.5] and a.position_source == "model" and a.time == T0 + 15
    assert any(n.startswith("no height given: used z of evidence memory") for n in a.notes)
    # not found: nothing is filled in
    a = build_answer(
        ModelAnswer(question_type="position", found=False), "Where is the cat?", wm, mem, "raven"
    )
    assert a.position is None and a.time is None and not a.evidence and a.position_source == "none"
    assert a.yaw is None and a.yaw_source == "none"
    # an unreadable time falls back to the evidence time and says so
    a = build_answer(ModelAnswer(evidence=[recs[3].id], time="teatime"), "When?", wm, mem, "raven")
    assert a.time == T0 + 30 and any("could not read the model's time" in n for n in a.notes)
    assert any("the model's time was unreadable: used the time of evidence memory" in n for n in a.notes)
    # question type from the wording when the model gives none
    assert build_answer(ModelAnswer(), "How long was I there?", wm, mem, "raven").question_type == "duration"


@pytest.mark.parametrize(
    "text",
    [
        "[" * 100_000,  # nesting deeper than the decoder's recursion limit
        "{" * 1_000_000,  # one failing decode per brace used to cost O(n) each: quadratic
        "[" * 1_000_000,
        ("{" + "x" * 999) * 150,  # brace after brace, far apart, inside the size limit
        "```json\n" + "{" * 150_000 + "\n```",
        "``` " * 60_000,
    ],
)
def test_extract_json_is_bounded_in_time(text):
    t0 = time.perf_counter()
    assert extract_json(text) is None
    # linear work is milliseconds; the quadratic kind this guards against takes minutes, so a
    # loose bound holds on a loaded machine and still fails it
    assert time.perf_counter() - t0 < 10.0


def test_extract_json_bounds_size_and_still_finds_late_objects():
    assert extract_json("x" * MAX_REPLY_CHARS + ' {"a": 1}') is None  # too long: a malformed reply
    assert (
        extract_json("{ not json " * (MAX_DECODE_ATTEMPTS + 1) + '{"a": 1}') is None
    )  # past the decode budget
    assert extract_json("{ not json " * 5 + '{"a": 1}') == {"a": 1}
    assert extract_json('[1, 2] then {"b": 2}') == {"b": 2}


def test_model_answer_heading_spellings():
    assert ModelAnswer.model_validate({"yaw_deg": 45}).yaw_deg == 45.0
    assert ModelAnswer.model_validate({"heading_deg": -30}).yaw_deg == -30.0
    # yaw and heading are radians, as the schema and ROS have them; strings are numbers too
    assert ModelAnswer.model_validate({"heading": -0.5}).yaw == -0.5
    assert ModelAnswer.model_validate({"yaw": "3.14"}).yaw == 3.14
    assert ModelAnswer.model_validate({}).yaw_deg is None
