"""A memory whose store is a Milvus server: `create --store` records the server as the user's
own, so the memory opens again; the same memory.json for a user who never gave that server is
refused before any connection (`ravenmem.memory.manifest.check_trusted`)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

import ravenmem
from ravenmem.errors import InputError
from ravenmem.types import Frame, Pose
from tests.conftest import ColorEmbedder, solid

pytestmark = pytest.mark.server


def test_create_trusts_its_server_and_another_user_must_opt_in(
    milvus_server: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    uri = f"milvus://{milvus_server}"
    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path / "alice"))
    monkeypatch.delenv("RAVENMEM_TRUSTED_STORES", raising=False)
    frames = [
        Frame(image=solid(c), t=100.0 + i, pose=Pose(i, 0, 0, 0), source="s", index=i)
        for i, c in enumerate(["red", "blue"])
    ]
    with ravenmem.create(tmp_path / "m.mem", embedder=ColorEmbedder(), ocr=False, store=uri) as mem:
        mem.add_frames(frames)
    trusted = json.loads((tmp_path / "alice" / "ravenmem" / "stores.json").read_text())["trusted"]
    assert trusted == [uri]
    with ravenmem.open(tmp_path / "m.mem") as mem:
        assert mem.count() == 2 and mem.info()["store"] == uri

    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path / "bob"))  # the folder, copied to Bob
    with pytest.raises(InputError, match="never gave ravenmem"):
        ravenmem.open(tmp_path / "m.mem")
    monkeypatch.setenv("RAVENMEM_TRUSTED_STORES", uri)
    with ravenmem.open(tmp_path / "m.mem") as mem:
        assert mem.count() == 2
