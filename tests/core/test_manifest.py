"""The manifest (`memory.json`) as a typed, checked object, and where it lets a store live."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from ravenmem.errors import InputError
from ravenmem.memory.manifest import FORMAT_VERSION, Manifest, confine, store_for_create, store_kind


def test_round_trip_keeps_unknown_keys(tmp_path: Path):
    data = {
        "embedder": "e",
        "dim": 8,
        "store": "local",
        "thumb_size": 320,
        "thumb_quality": 85,
        "ocr": True,
        "created": 1.5,
        "ingests": [{"kept": 3}],
        "format_version": 1,
        "added_later": {"x": 1},
    }
    (tmp_path / "memory.json").write_text(json.dumps(data))
    m = Manifest.load(tmp_path)
    assert (m.embedder, m.dim, m.thumb_size, m.ocr, m.ingests) == ("e", 8, 320, True, [{"kept": 3}])
    assert m.extra == {"added_later": {"x": 1}}
    m.ingests.append({"kept": 1})
    m.save(tmp_path)
    assert json.loads((tmp_path / "memory.json").read_text()) == data | {
        "ingests": [{"kept": 3}, {"kept": 1}]
    }


def test_defaults_of_old_manifests():
    m = Manifest.from_json({"embedder": "e", "dim": 4})
    assert (m.store, m.thumb_size, m.thumb_quality, m.ocr, m.format_version) == ("local", 0, 85, False, 1)


@pytest.mark.parametrize(
    "change,needle",
    [
        ({"dim": "abc"}, "field 'dim'"),
        ({"dim": 0}, "field 'dim'"),
        ({"dim": True}, "field 'dim'"),
        ({"dim": 4.0}, "field 'dim'"),
        ({"thumb_size": "big"}, "field 'thumb_size'"),
        ({"thumb_size": -1}, "field 'thumb_size'"),
        ({"thumb_quality": 0}, "field 'thumb_quality'"),
        ({"ocr": 1}, "field 'ocr'"),
        ({"created": float("nan")}, "field 'created'"),
        ({"ingests": [1]}, "field 'ingests'"),
        ({"embedder": ""}, "field 'embedder'"),
        ({"embedder": 3}, "field 'embedder'"),
        ({"format_version": FORMAT_VERSION + 1}, "newer ravenmem"),
        ({"format_version": 0}, "field 'format_version'"),
        ({"store": 7}, "field 'store'"),
    ],
)
def test_bad_fields_name_the_field(change: dict[str, object], needle: str):
    with pytest.raises(InputError, match=needle):
        Manifest.from_json({"embedder": "e", "dim": 4} | change)


def test_unreadable_files(tmp_path: Path):
    mf = tmp_path / "memory.json"
    for raw, needle in [
        (b"\xff\xfe{}", "not UTF-8"),
        (b"{", "not valid JSON"),
        (b"[" * 100_000, "JSON"),
        (b'"text"', "expected a JSON object"),
    ]:
        mf.write_bytes(raw)
        with pytest.raises(InputError, match=needle) as e:
            Manifest.load(tmp_path)
        assert str(mf) in str(e.value) and "\n" not in str(e.value)


@pytest.mark.parametrize(
    "value,kind",
    [
        ("local", "local"),
        ("milvus-lite:milvus.db", "lite"),
        ("milvus-lite:sub/m.db", "lite"),
        ("milvus://host:19530", "remote"),
        ("milvus://10.0.0.2:19530", "remote"),
        ("milvus://https://milvus.example.org", "remote"),
        ("milvus://http://h:19530/", "remote"),
    ],
)
def test_store_kinds(value: str, kind: str):
    assert store_kind(value) == kind


@pytest.mark.parametrize(
    "value",
    [
        "/elsewhere",
        "local:/elsewhere",
        "../x",
        "milvus-lite:../x.db",
        "milvus-lite:/abs/x.db",
        "milvus-lite:x.txt",
        "s3://bucket",
        "milvus://",
        "milvus://host",
        "milvus://ftp://h:1",
        "",
    ],
)
def test_store_values_refused(value: str):
    with pytest.raises(InputError, match="store"):
        store_kind(value)


def test_store_uri_stays_in_the_folder(tmp_path: Path):
    mem = tmp_path / "m.mem"
    mem.mkdir()
    m = Manifest(embedder="e", dim=4, store="local")
    assert m.store_uri(mem) == str(mem)
    m.store = "milvus-lite:milvus.db"
    assert m.store_uri(mem) == f"milvus://{mem.resolve() / 'milvus.db'}"
    m.store = "milvus://host:19530"
    assert m.store_uri(mem) == "milvus://host:19530"
    m.store = f"milvus://{mem.resolve() / 'old.db'}"  # older versions wrote absolute Lite paths
    assert m.store_uri(mem).endswith("m.mem/old.db")
    m.store = f"milvus://{tmp_path / 'outside.db'}"
    with pytest.raises(InputError, match="outside the memory folder"):
        m.store_uri(mem)
    (mem / "link").symlink_to(tmp_path)
    m.store = "milvus-lite:link/x.db"
    with pytest.raises(InputError, match="outside the memory folder"):
        m.store_uri(mem)


def test_store_for_create(tmp_path: Path, monkeypatch: pytest.MonkeyPatch):
    mem = tmp_path / "new.mem"
    assert store_for_create(None, mem) == "local"
    assert store_for_create(f"milvus://{mem / 'lite.db'}", mem) == "milvus-lite:lite.db"
    monkeypatch.chdir(tmp_path)
    assert store_for_create("milvus://new.mem/a/b.db", mem) == "milvus-lite:a/b.db"
    assert store_for_create("milvus://host:19530", mem) == "milvus://host:19530"
    for bad in (f"milvus://{tmp_path / 'x.db'}", "/elsewhere", "local:/x", "milvus://new.mem/x.sqlite"):
        with pytest.raises(InputError, match="--store"):
            store_for_create(bad, mem)


def test_confine(tmp_path: Path):
    (tmp_path / "m" / "thumbs").mkdir(parents=True)
    (tmp_path / "m" / "thumbs" / "a.jpg").write_bytes(b"x")
    (tmp_path / "m" / "thumbs" / "out").symlink_to(tmp_path)
    (tmp_path / "other.txt").write_text("private")
    mem = tmp_path / "m"
    assert confine(mem, "thumbs/a.jpg") == (mem / "thumbs" / "a.jpg").resolve()
    assert (
        confine(mem, "thumbs/out/m/thumbs/a.jpg") == (mem / "thumbs" / "a.jpg").resolve()
    )  # out and back in
    for bad in ("../m/thumbs/a.jpg", "/etc/passwd", "thumbs/out/other.txt", "", "a\x00b"):
        assert confine(mem, bad) is None
