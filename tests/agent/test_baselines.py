"""The baselines and the methods registry: same Answer schema, costs, and what each sends a model."""

from __future__ import annotations

import base64
import io
import re
from collections.abc import Sequence

import numpy as np
import pytest
from PIL import Image

from ravenmem.agent import (
    METHODS,
    CaptionAgent,
    CaptionIndex,
    EmbedderOnly,
    RandomBaseline,
    VLMOnly,
    caption_memories,
    create_method,
)
from ravenmem.agent.captions import CAPTION_FILE
from ravenmem.errors import InputError
from tests.agent.conftest import T0, config_for
from tests.agent.scripted_server import answer, tool
from tests.conftest import COLORS, ColorEmbedder


class ColorWords:
    """A text encoder for captions: the colour a text names (same space as ColorEmbedder texts)."""

    name = "test-color-words"

    def __call__(self, texts: Sequence[str]) -> np.ndarray:
        return ColorEmbedder().embed_texts([re.sub(r"[^a-z ]", " ", t.lower()) for t in texts])


def describe_image(body: dict) -> dict:
    """A scripted captioner: names the colour of the image it was sent."""
    url = next(
        p["image_url"]["url"] for m in body["messages"] for p in m["content"] if p["type"] == "image_url"
    )
    img = np.asarray(
        Image.open(io.BytesIO(base64.b64decode(url.split(",", 1)[1]))).convert("RGB"), dtype=float
    )
    mean = img.reshape(-1, 3).mean(0)
    name = min(COLORS, key=lambda c: float(np.sum((np.array(COLORS[c]) - mean) ** 2)))
    return {"content": f"  A plain wall painted {name}.\n"}


def test_registry_names_and_unknown():
    assert METHODS.names() == ["caption", "embedder-only", "offline", "random", "raven", "vlm-only"]
    with pytest.raises(InputError, match="unknown method 'gpt'"):
        create_method("gpt", None)  # type: ignore[arg-type]


def test_embedder_only_is_top1(mem):
    ans = create_method("embedder-only", mem).ask("Where is the magenta box?")
    assert isinstance(create_method("embedder-only", mem), EmbedderOnly)
    assert ans.method == "embedder-only" and ans.position == pytest.approx([7.0, 3.0, 0.5])
    assert ans.time == pytest.approx(T0 + 70) and ans.cost.alpha == pytest.approx(1 / 12)
    assert ans.yes is None and create_method("embedder-only", mem).ask("Is there a magenta box?").yes is True


def test_random_is_reproducible(mem):
    a = [RandomBaseline(mem, seed=3).ask("Did I see a cat?") for _ in range(2)]
    b = create_method("random", mem, seed=3)
    assert a[0].evidence[0].id == a[1].evidence[0].id == b.ask("Did I see a cat?").evidence[0].id
    ids = {RandomBaseline(mem, seed=s).ask("Where?").evidence[0].id for s in range(20)}
    assert len(ids) > 3


def test_vlm_only_sends_uniform_frames_in_one_prompt(mem, server):
    recs = mem.all_records()
    server.push(answer(question_type="position", evidence=[recs[7].id], answer="by the magenta wall"))
    m = create_method("vlm-only", mem, vlm=config_for(server), frames=4, max_tool_calls=9)
    assert isinstance(m, VLMOnly) and m.max_tool_calls == 0
    ans = m.ask("Where is the magenta box?")
    assert not ans.failed and len(server.requests) == 1 and "tools" not in server.requests[0]
    assert server.images(0) == 4
    listed = [int(i) for i in re.findall(r"^\[m(\d+)\]", server.texts(0), re.M)]
    assert listed == [recs[i].id for i in (0, 4, 7, 11)]  # uniform over the whole history, in order
    assert ans.position == pytest.approx([7.0, 3.0, 0.5])
    assert (
        ans.cost.memories_shown == 4 and ans.cost.alpha == pytest.approx(4 / 12) and ans.cost.tool_calls == 0
    )
    assert "at most" not in server.requests[0]["messages"][0]["content"]  # no tools are promised


def test_vlm_only_refuses_tool_requests(mem, server):
    from tests.agent.scripted_server import json_tool

    recs = mem.all_records()
    server.push(json_tool("search_text", query="x"), answer(question_type="text", evidence=[recs[0].id]))
    ans = VLMOnly(mem, vlm=config_for(server), frames=3).ask("What did I see?")
    assert not ans.failed and ans.cost.tool_calls == 0 and "used all 0 tool calls" in server.texts(1)


def test_vlm_methods_need_a_vlm(mem, monkeypatch, tmp_path):
    monkeypatch.delenv("RAVENMEM_VLM_MODEL", raising=False)
    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path))
    with pytest.raises(InputError, match="needs a VLM"):
        create_method("vlm-only", mem)
    with pytest.raises(InputError, match="needs a VLM"):
        create_method("caption", mem, encoder=ColorWords())


def test_caption_memories_is_incremental_and_crash_safe(mem, server):
    server.default = describe_image
    n = caption_memories(mem, config_for(server), encoder=ColorWords(), batch=5)
    assert n == 12 and len(server.requests) == 12 and (mem.path / CAPTION_FILE).exists()
    idx = CaptionIndex(mem, ColorWords())
    recs = mem.all_records()
    assert idx.caption(recs[1].id) == "A plain wall painted red." and len(idx) == 12
    hits = idx.search("the red wall", k=2)
    assert {h.memory.id for h in hits} == {recs[1].id, recs[8].id} and hits[0].score == pytest.approx(
        1.0, abs=1e-5
    )
    late = idx.search("red", k=2, after=T0 + 50)
    assert late[0].memory.id == recs[8].id and all(h.memory.t >= T0 + 50 for h in late)
    assert [h.memory.id for h in idx.search("blue", k=3, near=(6.0, 2.0, 0.5))] == [recs[6].id]
    idx.close()
    assert caption_memories(mem, config_for(server), encoder=ColorWords()) == 0  # nothing new
    assert len(server.requests) == 12
    with pytest.raises(InputError, match="were embedded with"):
        CaptionIndex(mem, ColorEmbedder().embed_texts)  # another encoder name


def test_caption_agent_answers_over_text_only(mem, server):
    recs = mem.all_records()
    server.default = describe_image
    agent = CaptionAgent(mem, vlm=config_for(server), encoder=ColorWords())  # auto-captions first
    assert len(server.requests) == 12
    server.requests.clear()
    server.default = None
    server.push(
        tool("search_text", query="a red wall"), answer(question_type="position", evidence=[recs[8].id])
    )
    ans = agent.ask("Where is the red wall?", image=np.zeros((8, 8, 3), np.uint8))
    assert not ans.failed and ans.method == "caption" and ans.position == pytest.approx([8.0, 3.0, 0.5])
    assert server.images(0) == server.images(1) == 0  # text only, even with a query image
    assert "search_image" not in server.tool_names(0)
    text = next(m["content"] for m in server.requests[1]["messages"] if m["role"] == "tool")
    assert 'caption: "A plain wall painted red."' in text and "image attached" not in text
    assert "text captions of camera images" in server.requests[0]["messages"][0]["content"]


def test_create_method_passes_only_relevant_options(mem, server):
    opts = dict(vlm=config_for(server), top_k=2, max_tool_calls=1, frames=3, seed=1, trace_path=None)
    for name in ("raven", "offline", "embedder-only", "random", "vlm-only"):
        m = create_method(name, mem, **opts)
        assert m.name == name
    assert create_method("raven", mem, **opts).top_k == 2
