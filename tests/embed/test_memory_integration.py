"""The offline embedder inside a real memory: ingest TUM frames, search by text, reopen by name."""

from __future__ import annotations

from pathlib import Path

import ravenmem
from ravenmem.types import Frame, Pose

KEYBOARD = ["1305031233.793747.jpg", "1305031238.861826.jpg", "1305031241.793694.jpg"]  # frames 128, 280, 368
NO_KEYBOARD = ["1305031234.861873.jpg", "1305031237.529735.jpg", "1305031240.461673.jpg"]  # 160, 240, 328


def test_memory_search_and_reopen_with_stored_embedder_name(tmp_path: Path, offline, tum_frame) -> None:
    names = KEYBOARD + NO_KEYBOARD
    frames = [
        # 10 s apart: six separate moments, so diverse results may return all three keyboard frames
        Frame(image=tum_frame(n), t=1305031229.0 + 10 * i, pose=Pose(0.1 * i, 0.0), source="tum", index=i)
        for i, n in enumerate(names)
    ]
    mem = ravenmem.create(tmp_path / "desk.mem", embedder=offline, ocr=False, thumb_size=0)
    mem.add_frames(frames)
    hits = mem.search_text("a computer keyboard", k=3)
    assert sorted(h.memory.frame_index for h in hits) == [0, 1, 2]
    mem.close()

    with ravenmem.open(tmp_path / "desk.mem") as again:  # embedder rebuilt from the stored name
        assert again.embedder.name == offline.name
        assert again.embedder is not offline
        hits2 = again.search_text("a computer keyboard", k=3)
        assert [h.memory.id for h in hits2] == [h.memory.id for h in hits]
        assert [round(h.score, 5) for h in hits2] == [round(h.score, 5) for h in hits]
