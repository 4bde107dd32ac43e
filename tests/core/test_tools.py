"""The one table of tools: argument checking, schemas, and each tool run through it."""

from __future__ import annotations

import json

import pytest

import ravenmem
from ravenmem.errors import InputError
from ravenmem.memory.protocol import MAX_K, check_k
from ravenmem.tools import TOOLS, get_tool, hit_json
from ravenmem.types import Frame, Pose
from tests.conftest import solid

T0 = 1_700_000_000.0
SEQ = ["red", "green", "blue", "yellow", "red", "cyan", "magenta", "blue", "white", "green"]


@pytest.fixture
def mem(tmp_path, color_embedder):
    m = ravenmem.create(tmp_path / "m.mem", embedder=color_embedder, ocr=False, thumb_size=32)
    m.add_frames(
        [
            Frame(image=solid(c), t=T0 + 10 * i, pose=Pose(float(i), 0.0, 0.0, 0.1 * i), source="s", index=i)
            for i, c in enumerate(SEQ)
        ]
    )
    yield m
    m.close()


def test_the_table_has_the_papers_four_tools_in_order():
    assert list(TOOLS) == ["search_text", "search_image", "search_time", "search_position"]
    assert [t.order for t in TOOLS.values()] == ["best first", "best first", "chronological", "nearest first"]
    assert get_tool("time") is TOOLS["search_time"]
    with pytest.raises(InputError, match="unknown tool 'search_smell'"):
        get_tool("search_smell")


def test_plain_schemas_have_no_anyof_null_or_refs():
    for tool in TOOLS.values():
        text = json.dumps(tool.plain_schema())
        assert "anyOf" not in text and "null" not in text and "$ref" not in text, tool.name
    assert TOOLS["search_text"].plain_schema()["required"] == ["query"]
    assert TOOLS["search_position"].plain_schema()["properties"]["z"]["type"] == "number"
    assert TOOLS["search_time"].plain_schema()["properties"]["time"]["type"] == "string"
    assert "memory_id" in TOOLS["search_image"].plain_schema()["properties"]


@pytest.mark.parametrize(
    ("tool", "args", "msg"),
    [
        ("search_text", {"query": "   "}, "query"),
        ("search_text", {"query": "x", "bogus": 1}, "bogus"),
        ("search_text", {"query": "x", "near": [1, 2, 0]}, "near"),
        ("search_position", {"x": float("nan"), "y": 0}, "x"),
        ("search_position", {"x": 0, "y": 0, "radius": -1}, "radius"),
        ("search_time", {"time": float("inf")}, "time"),
        ("search_image", {"memory_id": -3}, "memory_id"),
    ],
)
def test_bad_arguments_are_one_line_errors_naming_the_field(tool, args, msg):
    with pytest.raises(InputError) as e:
        TOOLS[tool].validate(args)
    assert msg in str(e.value) and "\n" not in str(e.value)


@pytest.mark.parametrize("k", [0, -1, MAX_K + 1, 2**63, "5", 2.0, True, None])
def test_k_is_a_whole_number_in_range(k):
    with pytest.raises(InputError, match="k must be"):
        check_k(k)


def test_each_tool_runs_through_the_table(mem):
    text = TOOLS["search_text"].run(mem, {"query": "red"}, k=2)
    assert {h.memory.frame_index for h in text} == {0, 4}
    like = TOOLS["search_image"].run(mem, {"memory_id": text[0].memory.id}, k=1)
    assert like[0].memory.id != text[0].memory.id and like[0].memory.frame_index in (0, 4)
    with pytest.raises(InputError, match="memory_id"):
        TOOLS["search_image"].run(mem, {}, k=1)
    attached = TOOLS["search_image"].run(mem, {}, k=2, image=solid("blue"))
    assert {h.memory.frame_index for h in attached} == {2, 7}
    fwd = TOOLS["search_time"].run(mem, {"time": "+45"}, k=3)
    assert [h.memory.frame_index for h in fwd] == [5, 6, 7]
    mid = TOOLS["search_time"].run(mem, {"time": "+45"}, k=4, time_mode="centred")
    assert [h.memory.frame_index for h in mid] == [3, 4, 5, 6]
    first = TOOLS["search_time"].run(mem, {"time": "start"}, k=4, time_mode="centred")
    assert [h.memory.frame_index for h in first] == [0, 1, 2, 3]
    pos = TOOLS["search_position"].run(mem, {"x": 6.2, "y": 0}, k=2)
    assert [h.memory.frame_index for h in pos] == [6, 7] and pos[0].distance == pytest.approx(0.2)


def test_hit_json_is_the_one_shape(mem):
    h = TOOLS["search_position"].run(mem, {"x": 3, "y": 0}, k=1)[0]
    row = hit_json(h, 1, T0)
    assert row["offset_s"] == 30.0 and row["time"].endswith("Z") and row["yaw_deg"] == pytest.approx(17.19)
    assert set(row) >= {"rank", "id", "score", "distance", "t", "x", "y", "z", "yaw", "image"}
