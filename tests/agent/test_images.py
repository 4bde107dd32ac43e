"""What reaches the model: only pictures that decode, only files inside the memory folder."""

from __future__ import annotations

import base64
import io
import json
import sqlite3

import numpy as np
from PIL import Image

import ravenmem
from ravenmem.agent import Agent
from tests.agent.conftest import config_for
from tests.agent.scripted_server import answer, tool
from tests.conftest import ColorEmbedder


def jpeg(path, colour=(10, 200, 30)) -> bytes:
    arr = np.zeros((24, 32, 3), np.uint8)
    arr[:] = colour
    Image.fromarray(arr).save(path, format="JPEG")
    return path.read_bytes()


def test_only_decodable_images_inside_the_memory_are_sent(mem_path, tmp_path, server):
    secret = jpeg(tmp_path / "secret.jpg")
    (mem_path / "thumbs" / "notes.jpg").write_text("password=hunter2")
    (mem_path / "thumbs" / "link.jpg").symlink_to(tmp_path / "secret.jpg")
    with sqlite3.connect(mem_path / "store.sqlite") as db:
        ids = [r[0] for r in db.execute("SELECT id FROM memories ORDER BY t")]
        for mid, path in zip(
            ids, ["../secret.jpg", str(tmp_path / "secret.jpg"), "thumbs/notes.jpg", "thumbs/link.jpg"]
        ):
            db.execute("UPDATE memories SET image_path = ? WHERE id = ?", (path, mid))
    server.push(tool("search_time", time="+0"), answer(question_type="text", answer="ok", evidence=[]))
    with ravenmem.open(mem_path, embedder=ColorEmbedder()) as mem:
        ans = Agent(mem, vlm=config_for(server), top_k=12).ask("What did I see first?")
    text = next(m["content"] for m in server.requests[1]["messages"] if m["role"] == "tool")
    lines = text.splitlines()[1:]
    assert [("(no image stored)" in line) for line in lines] == [True] * 4 + [False] * 8
    assert server.images(1) == 8 and ans.cost.images == 8
    sent = json.dumps(server.requests[1])
    assert base64.b64encode(secret).decode() not in sent and "hunter2" not in sent
    for part in (
        p for m in server.requests[1]["messages"] if isinstance(m["content"], list) for p in m["content"]
    ):
        if part["type"] == "image_url":  # every picture sent decodes
            Image.open(io.BytesIO(base64.b64decode(part["image_url"]["url"].split(",", 1)[1]))).load()
