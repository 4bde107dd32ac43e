"""The Memory facade refuses nonsense with one-line errors, stays inside its folder, and a failed
create leaves nothing behind (Python API; the CLI side is in tests/cli/test_cli_*.py)."""

from __future__ import annotations

import sqlite3
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

import ravenmem
from ravenmem.embed.base import EMBEDDERS
from ravenmem.errors import EmbedderMismatchError, InputError
from ravenmem.memory.manifest import Manifest
from ravenmem.store.base import STORES
from ravenmem.types import Frame, Pose
from tests.conftest import ColorEmbedder, solid

T0 = 1_700_000_000.0
EMBEDDERS.register("test-color-alias")(lambda spec, **kw: ColorEmbedder())  # a spec whose name differs


@pytest.fixture
def mem(tmp_path):
    m = ravenmem.create(tmp_path / "m.mem", embedder=ColorEmbedder(), ocr=False, thumb_size=32)
    m.add_frames(
        [
            Frame(image=solid(c), t=T0 + 10 * i, pose=Pose(float(i), 0.0, 0.0), index=i)
            for i, c in enumerate(["red", "green", "blue", "red"])
        ]
    )
    yield m
    m.close()


@pytest.mark.parametrize("k", [-1, 0, 2**63, "5", 2.0, True, None])
def test_bad_k_is_refused_by_every_search(mem, k):
    calls = [
        lambda: mem.search_text("red", k=k),
        lambda: mem.search_texts(["red"], k=k),
        lambda: mem.search_image(solid("red"), k=k),
        lambda: mem.search_image(memory_id=1, k=k),
        lambda: mem.search_time("+0", k=k),
        lambda: mem.search_time("+0", k=k, centred=True),
        lambda: mem.search_position(0, 0, k=k),
        lambda: mem.query().limit(k),
    ]
    for call in calls:
        with pytest.raises(InputError, match="k must be"):
            call()


def test_k_of_numpy_type_is_fine(mem):
    assert len(mem.search_text("red", k=np.int64(2))) == 2


@pytest.mark.parametrize(
    "call,needle",
    [
        (lambda m: m.search_time(float("nan")), "finite"),
        (lambda m: m.search_time("1e400"), "finite"),
        (lambda m: m.search_text("red", after=float("inf")), "finite"),
        (lambda m: m.search_text("red", before="-inf"), "finite"),
        (lambda m: m.search_text("red", near=(float("nan"), 2, 5)), "near"),
        (lambda m: m.search_text("red", near=(1, 2, float("inf"))), "near"),
        (lambda m: m.search_text("red", near=(1, 2, 0)), "near"),
        (lambda m: m.search_text("red", near=(1, 2)), "near"),
        (lambda m: m.search_text("red", near="abc"), "near"),
        (lambda m: m.search_position(float("nan"), 0), "x must be a finite"),
        (lambda m: m.search_position(0, float("-inf")), "y must be a finite"),
        (lambda m: m.search_position(0, 0, z=float("inf")), "z must be a finite"),
        (lambda m: m.search_position(0, 0, radius=float("nan")), "radius"),
        (lambda m: m.search_position(0, 0, radius=0), "radius"),
        (lambda m: m.search_position("a", 0), "x must be a number"),
        (lambda m: m.search_text("caf\udcff"), "not valid UTF-8"),
        (lambda m: m.search_text(5), "must be a string"),
        (lambda m: m.search_texts("red"), "list of text queries"),
    ],
)
def test_nonsense_is_one_line_input_error(mem, call, needle):
    with pytest.raises(InputError, match=needle) as e:
        call(mem)
    assert "\n" not in str(e.value)


def test_query_is_immutable(mem):
    base = mem.query().after("+5")
    red = base.text("red").limit(1)
    near = base.position(3.0, 0.0)
    assert base.mode is None and base.k == 5
    assert [h.memory.frame_index for h in red.run()] == [3]
    assert [h.memory.frame_index for h in near.run()][:2] == [3, 2]
    assert [h.memory.frame_index for h in base.run()] == [1, 2, 3]
    with pytest.raises(InputError, match="one mode"):
        red.time("+0")


def _set_image_path(mem_path: Path, rid: int, value: str) -> None:
    con = sqlite3.connect(mem_path / "store.sqlite")
    con.execute("UPDATE memories SET image_path = ? WHERE id = ?", (value, rid))
    con.commit()
    con.close()


def test_image_paths_are_confined_to_the_folder(tmp_path, mem):
    outside = tmp_path / "private.jpg"
    Image.new("RGB", (8, 8)).save(outside)
    (mem.path / "thumbs" / "link.jpg").symlink_to(outside)
    (mem.path / "thumbs" / "bad.jpg").write_bytes(b"not a jpeg")
    path = mem.path
    mem.close()
    for rid, value in [
        (1, "../private.jpg"),
        (2, str(outside)),
        (3, "thumbs/link.jpg"),
        (4, "thumbs/bad.jpg"),
    ]:
        _set_image_path(path, rid, value)
    with ravenmem.open(path) as m:
        recs = {r.id: r for r in m.all_records()}
        assert [m.image_file(recs[i]) for i in (1, 2, 3)] == [None, None, None]
        assert m.image_file(recs[4]) == (path / "thumbs" / "bad.jpg").resolve()
        assert all(m.load_image(recs[i]) is None for i in (1, 2, 3, 4))  # 4: does not decode
    with ravenmem.open(path, external_images=True) as m:  # the user's opt-in: absolute paths only
        recs = {r.id: r for r in m.all_records()}
        assert m.image_file(recs[2]) == outside and m.load_image(recs[2]) is not None
        assert m.image_file(recs[1]) is None and m.image_file(recs[3]) is None


def test_thumb_size_zero_keeps_original_paths_read_only_on_opt_in(tmp_path):
    frame_file = tmp_path / "frame.png"
    Image.fromarray(solid("blue")).save(frame_file)
    with ravenmem.create(tmp_path / "z.mem", embedder=ColorEmbedder(), ocr=False, thumb_size=0) as m:
        m.add_frames([Frame(image=solid("blue"), t=T0, pose=Pose(0, 0), path=str(frame_file))])
        rec = m.all_records()[0]
        assert rec.image_path == str(frame_file.resolve()) and m.image_file(rec) is None
    with ravenmem.open(tmp_path / "z.mem", external_images=True) as m:
        assert m.load_image(m.all_records()[0]) is not None


def test_open_resolves_an_embedder_spec_before_comparing(mem):
    path = mem.path
    mem.close()
    with ravenmem.open(path, embedder="test-color-alias") as m:  # spec != stored name, same embedder
        assert m.count() == 4
    with ravenmem.create(path, embedder="test-color-alias", exist_ok=True) as m:
        assert m.count() == 4
    with pytest.raises(EmbedderMismatchError, match="built with embedder 'test-color'"):
        ravenmem.open(path, embedder="offline")


def test_memory_holds_a_typed_manifest(mem):
    assert isinstance(mem.manifest, Manifest) and mem.manifest.dim == 4 and mem.dim == 4
    mem.record_ingest({"source": "x", "frames_seen": "many", "kept": 1})  # counted 0, not a crash
    assert Manifest.load(mem.path).ingests[-1]["source"] == "x"
    info = mem.info()
    assert info["frames_seen"] == 0 and info["extent"] == {"x": [0.0, 3.0], "y": [0.0, 0.0], "z": [0.0, 0.0]}


def test_create_only_in_a_new_or_empty_folder(tmp_path):
    busy = tmp_path / "busy"
    busy.mkdir()
    (busy / "notes.txt").write_text("mine")
    with pytest.raises(InputError, match="other files"):
        ravenmem.create(busy, embedder=ColorEmbedder())
    assert sorted(p.name for p in busy.iterdir()) == ["notes.txt"]
    empty = tmp_path / "empty"
    empty.mkdir()
    ravenmem.create(empty, embedder=ColorEmbedder()).close()
    assert (empty / "memory.json").is_file()


def test_undo_create_on_error_removes_exactly_what_create_made(tmp_path):
    new = tmp_path / "a" / "b" / "m.mem"
    with (
        pytest.raises(RuntimeError),
        ravenmem.create(new, embedder=ColorEmbedder()) as m,
        m.undo_create_on_error(),
    ):
        raise RuntimeError("ingest failed")
    assert not (tmp_path / "a").exists()

    empty = tmp_path / "empty"
    empty.mkdir()
    with (
        pytest.raises(RuntimeError),
        ravenmem.create(empty, embedder=ColorEmbedder()) as m,
        m.undo_create_on_error(),
    ):
        raise RuntimeError("ingest failed")
    assert empty.is_dir() and list(empty.iterdir()) == []

    kept = tmp_path / "kept.mem"
    with (
        pytest.raises(RuntimeError),
        ravenmem.create(kept, embedder=ColorEmbedder()) as m,
        m.undo_create_on_error(),
    ):
        m.add(solid("red"), Pose(0, 0), T0)
        raise RuntimeError("failed after storing one memory")
    with (
        ravenmem.open(kept) as m,
        pytest.raises(RuntimeError),
        m.undo_create_on_error(),
    ):  # opened: never removed
        raise RuntimeError("later failure")
    assert ravenmem.open(kept).count() == 1


def test_create_removes_what_it_made_when_the_store_fails(tmp_path, monkeypatch):
    with pytest.raises(InputError, match="inside the memory folder"):  # refused before anything is made
        ravenmem.create(tmp_path / "x.mem", embedder=ColorEmbedder(), store=f"milvus://{tmp_path / 'x.db'}")
    assert not (tmp_path / "x.mem").exists()

    def unreachable(spec: str, **kw: object) -> None:
        assert (Path(spec) / "memory.json").is_file()  # the manifest is written first
        raise ConnectionRefusedError("store server unreachable")

    monkeypatch.setitem(STORES._factories, "local", unreachable)
    with pytest.raises(ConnectionRefusedError):
        ravenmem.create(tmp_path / "a" / "b.mem", embedder=ColorEmbedder())
    assert sorted(p.name for p in tmp_path.iterdir()) == []
