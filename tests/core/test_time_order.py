"""The time tool's three orderings (the paper's ordering study): forward, centred, nearest."""

from __future__ import annotations

import pytest

import ravenmem
from ravenmem.agent.tool_calls import ToolRunner, WorkingMemory
from ravenmem.errors import InputError
from ravenmem.tools import TOOLS
from ravenmem.types import Frame, Pose
from tests.conftest import solid

T0 = 1_700_000_000.0


@pytest.fixture
def mem(tmp_path, color_embedder):
    m = ravenmem.create(tmp_path / "m.mem", embedder=color_embedder, ocr=False, thumb_size=32)
    # memories at +0, +10, ..., +90 s
    m.add_frames(
        [
            Frame(image=solid("red"), t=T0 + 10 * i, pose=Pose(float(i), 0.0), source="s", index=i)
            for i in range(10)
        ]
    )
    yield m
    m.close()


def offsets(hits) -> list[float]:
    return [round(h.memory.t - T0) for h in hits]


def test_forward_centred_and_nearest(mem):
    tool = TOOLS["search_time"]
    at = {"time": T0 + 52}
    assert offsets(tool.run(mem, at, 3)) == [60, 70, 80]  # from the time on, chronological
    assert offsets(tool.run(mem, at, 3, time_mode="centred")) == [50, 60, 70]  # around it, chronological
    assert offsets(tool.run(mem, at, 3, time_mode="nearest")) == [50, 60, 40]  # nearest first, either side
    assert offsets(tool.run(mem, {"time": T0 + 95}, 2, time_mode="nearest")) == [90, 80]  # past the end
    assert "nearest in time first" in tool.description(3, time_mode="nearest")
    assert "nearest in time first" in tool.order_for(tool.validate(at), "nearest")


def test_the_agent_lists_them_nearest_first(mem):
    runner = ToolRunner(mem, 2, time_mode="nearest")
    out = runner.run("search_time", {"time": T0 + 38}, WorkingMemory())
    assert out.text.startswith("search_time(time=") and "nearest in time first" in out.text.splitlines()[0]
    assert offsets(out.hits) == [40, 30]
    with pytest.raises(InputError, match="time_mode must be forward, centred or nearest"):
        ToolRunner(mem, 2, time_mode="sideways")
