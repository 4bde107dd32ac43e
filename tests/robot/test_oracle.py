"""Oracle perception: label vectors rank the keyframe that shows an object largest first, texts
that name no known object match nothing, and the oracle memory keeps the robot's poses."""

from __future__ import annotations

import numpy as np
import pytest

import ravenmem
from ravenmem.errors import InputError
from ravenmem.robot.oracle import LabelEmbedder, oracle_memory
from ravenmem.types import Frame, Pose


def test_label_vectors_and_texts() -> None:
    emb = LabelEmbedder(["Shotgun", "ExplosiveBarrel", "Shotgun"])
    assert emb.kinds == ["ExplosiveBarrel", "Shotgun"] and emb.dim == 4
    near, far, other = (
        emb.embed_labels({"Shotgun": 4000}),
        emb.embed_labels({"Shotgun": 100}),
        emb.embed_labels({"ExplosiveBarrel": 4000}),
    )
    q = emb.embed_texts(["Where did you see the shotgun?"])[0]
    assert q @ near > q @ far > 0 and q @ other == 0
    assert np.allclose([np.linalg.norm(v) for v in (near, far, other)], 1.0)
    decoy = emb.embed_texts(["a purple elephant"])[0]
    assert decoy @ near == 0 and decoy @ emb.embed_labels({}) == 0
    with pytest.raises(InputError, match="labels"):
        emb.embed_images([np.zeros((2, 2, 3), np.uint8)])
    # the name rebuilds the same embedder (a memory records it)
    from ravenmem.embed.base import create_embedder

    again = create_embedder(emb.name)
    assert again.name == emb.name and again.dim == emb.dim


def test_oracle_memory_keeps_poses_and_finds_the_largest_view(tmp_path, color_embedder) -> None:
    mem = ravenmem.create(tmp_path / "m.mem", embedder=color_embedder, ocr=False)
    ids = mem.add_frames(
        [
            Frame(np.full((8, 8, 3), 40 * i, np.uint8), 100.0 + i, Pose(float(i), 0.0), "sim", i)
            for i in range(4)
        ]
    )
    px = {ids[0]: {7: 200}, ids[1]: {7: 3000, 9: 500}, ids[2]: {9: 2000}, ids[3]: {}}
    om = oracle_memory(tmp_path / "o.mem", mem, px, {7: "Shotgun", 9: "Medikit"})
    assert [r.pose.x for r in om.all_records()] == [0.0, 1.0, 2.0, 3.0]
    assert om.search_text("the shotgun", k=1)[0].memory.pose.x == 1.0
    assert om.search_text("a first aid kit", k=1)[0].memory.pose.x == 2.0
    om.close()
    back = ravenmem.open(tmp_path / "o.mem")  # reopens: the name rebuilds the label embedder
    assert back.search_text("shotgun", k=2)[1].memory.pose.x == 0.0
