"""What a memory folder may make ravenmem do: read and write only inside that folder, and never
touch a folder or a database that is not a ravenmem memory (subprocesses, as a user runs them)."""

from __future__ import annotations

import base64
import hashlib
import http.server
import json
import os
import shutil
import sqlite3
import threading
from collections.abc import Iterator
from pathlib import Path

import pytest
from PIL import Image

import ravenmem
from ravenmem.embed.base import create_embedder
from tests.agent.scripted_server import ScriptedModel, answer
from tests.cli.helpers import ForkedCli, assert_one_line_error, make_memory, run_cli
from tests.cli.test_cli_defaults import imported


def tree(folder: Path) -> dict[str, str]:
    """Every file under `folder` with the hash of its bytes."""
    return {
        str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(folder.rglob("*"))
        if p.is_file()
    }


def foreign_db(path: Path) -> Path:
    """Another program's SQLite database (rollback journal, its own tables)."""
    con = sqlite3.connect(path)
    con.execute("CREATE TABLE customers (id INTEGER PRIMARY KEY, name TEXT)")
    con.execute("INSERT INTO customers (name) VALUES ('Ada')")
    con.commit()
    con.close()
    return path


def journal_mode(path: Path) -> str:
    con = sqlite3.connect(f"file:{path}?mode=ro", uri=True)
    try:
        return str(con.execute("PRAGMA journal_mode").fetchone()[0])
    finally:
        con.close()


@pytest.fixture
def frames(tmp_path: Path) -> Path:
    """An image folder with a pose file: the smallest real source `ingest` takes."""
    src = tmp_path / "frames"
    src.mkdir()
    for i in range(3):
        Image.new("RGB", (64, 48), (80 * i, 40, 200 - 60 * i)).save(src / f"frame_{i}.png")
    (src / "poses.csv").write_text(
        "file,t,x,y\n" + "".join(f"frame_{i}.png,{1000 + i},{i},0\n" for i in range(3))
    )
    return src


# ---------------------------------------------------------------- folders that are not memories
def test_ingest_never_writes_into_a_folder_that_is_not_a_memory(tmp_path: Path, frames: Path):
    other = tmp_path / "otherapp"
    other.mkdir()
    db = foreign_db(other / "store.sqlite")
    before = tree(other)
    line = assert_one_line_error(run_cli("ingest", str(frames), "-m", str(other), "--no-ocr"))
    assert "other files" in line and "nothing was written" in line
    assert tree(other) == before and journal_mode(db) == "delete"


def test_a_foreign_store_sqlite_is_refused_unchanged(forked_cli: ForkedCli, tmp_path: Path, frames: Path):
    mem = make_memory(tmp_path / "m.mem", n=2)
    db = mem / "store.sqlite"
    db.unlink()
    for f in mem.glob("index.faiss"):
        f.unlink()
    foreign_db(db)
    mf = mem / "memory.json"  # built by the default embedder, so that `ingest` gets as far as the store
    offline = create_embedder("offline")
    mf.write_text(json.dumps(json.loads(mf.read_text()) | {"embedder": offline.name, "dim": offline.dim}))
    before = tree(mem)
    for args in (["info"], ["search", "--time", "0"], ["ingest", str(frames), "--no-ocr"]):
        line = assert_one_line_error(forked_cli(*args, "-m", str(mem)))
        assert "store.sqlite" in line and "not a ravenmem store" in line
    assert tree(mem) == before and journal_mode(db) == "delete"  # no WAL switch, no -wal/-shm files


def test_a_store_sqlite_that_is_no_database_is_refused(tmp_path: Path):
    mem = make_memory(tmp_path / "m.mem", n=2)
    (mem / "store.sqlite").write_bytes(b"just some text\n" * 10)
    before = tree(mem)
    line = assert_one_line_error(run_cli("search", "--time", "0", "-m", str(mem)))
    assert "not a SQLite database" in line and tree(mem) == before


def test_memory_pointing_at_a_database_file(forked_cli: ForkedCli, tmp_path: Path, frames: Path):
    db = foreign_db(tmp_path / "shop.sqlite")
    before = db.read_bytes()
    assert "not a ravenmem memory" in assert_one_line_error(forked_cli("info", "-m", str(db)))
    assert "not a folder" in assert_one_line_error(forked_cli("ingest", str(frames), "-m", str(db)))
    assert db.read_bytes() == before and journal_mode(db) == "delete"
    assert sorted(os.listdir(tmp_path)) == ["frames", "shop.sqlite"]


# ---------------------------------------------------------------- the manifest
@pytest.mark.parametrize(
    "edit,needle",
    [
        (b'{"embedder": "caf\xe9", "dim": 4}', "not UTF-8"),
        ({"dim": "abc"}, "field 'dim'"),
        ({"thumb_size": "big"}, "field 'thumb_size'"),
        ({"format_version": 999}, "format_version 999 was written by a newer ravenmem"),
        ({"ocr": "yes"}, "field 'ocr'"),
        ({"ingests": "many"}, "field 'ingests'"),
        (b"[1, 2, 3]", "expected a JSON object"),
        (b'{"dim": 4}', "'embedder' is missing"),
        (b"{not json", "not valid JSON"),
    ],
)
def test_a_bad_manifest_is_one_line_and_nothing_is_written(
    forked_cli: ForkedCli, tmp_path: Path, edit: object, needle: str
):
    mem = make_memory(tmp_path / "m.mem", n=2)
    mf = mem / "memory.json"
    if isinstance(edit, bytes):
        mf.write_bytes(edit)
    else:
        mf.write_text(json.dumps(json.loads(mf.read_text()) | edit))  # type: ignore[operator]
    before = tree(mem)
    line = assert_one_line_error(forked_cli("search", "--time", "0", "-m", str(mem)))
    assert needle in line and "memory.json" in line
    assert tree(mem) == before


@pytest.mark.parametrize(
    "store",
    [
        "ELSEWHERE",
        "local:ELSEWHERE",
        "milvus://ELSEWHERE/x.db",
        "milvus-lite:../x.db",
        "s3://bucket/x",
        "../up",
    ],
)
def test_the_manifest_store_cannot_point_outside_the_folder(
    forked_cli: ForkedCli, tmp_path: Path, frames: Path, store: str
):
    mem = make_memory(tmp_path / "m.mem", n=2)
    elsewhere = tmp_path / "elsewhere"
    mf = mem / "memory.json"
    mf.write_text(
        json.dumps(json.loads(mf.read_text()) | {"store": store.replace("ELSEWHERE", str(elsewhere))})
    )
    commands = [["info"], ["ingest", str(frames), "--no-ocr"]] if store == "ELSEWHERE" else [["info"]]
    for args in commands:
        line = assert_one_line_error(forked_cli(*args, "-m", str(mem)))
        assert "store" in line
    assert not elsewhere.exists() and not (tmp_path / "x.db").exists() and not (tmp_path / "up").exists()


def test_create_refuses_a_milvus_lite_file_outside_the_memory(tmp_path: Path, frames: Path):
    outside = tmp_path / "lite" / "x.db"
    line = assert_one_line_error(
        run_cli("ingest", str(frames), "-m", str(tmp_path / "m.mem"), "--store", f"milvus://{outside}")
    )
    assert "inside the memory folder" in line
    assert not (tmp_path / "m.mem").exists() and not outside.parent.exists()


# ---------------------------------------------------------------- image paths read from a memory
def test_ask_never_sends_files_outside_the_memory(tmp_path: Path):
    """Records whose image_path leaves the folder (`..`, an absolute path, a symlink) are not
    read: the VLM receives the memory's own thumbnails only."""
    secret = tmp_path / "secret"
    secret.mkdir()
    private = secret / "private.jpg"
    Image.new("RGB", (40, 30), (1, 2, 3)).save(private)
    notes = secret / "notes.txt"
    notes.write_text("password=hunter2\n")
    mem = make_memory(tmp_path / "home" / "m.mem", n=4)
    (mem / "thumbs" / "link.jpg").symlink_to(private)
    con = sqlite3.connect(mem / "store.sqlite")
    for i, path in enumerate(["../../secret/private.jpg", str(notes), "thumbs/link.jpg"], start=1):
        con.execute("UPDATE memories SET image_path = ? WHERE id = ?", (path, i))
    con.commit()
    con.close()
    with ravenmem.open(mem) as m:
        recs = m.all_records()
        assert [m.image_file(r) is None for r in recs] == [True, True, True, False]
        assert [m.load_image(r) is None for r in recs] == [True, True, True, False]

    leaked = [base64.b64encode(p.read_bytes()).decode()[:40] for p in (private, notes)]
    env = {"XDG_CONFIG_HOME": str(tmp_path), "RAVENMEM_VLM_API_KEY": "k"}
    with ScriptedModel(default=answer(question_type="text", answer="no idea", evidence=[])) as srv:
        r = run_cli(
            "ask",
            "What did I see?",
            "-m",
            str(mem),
            "--method",
            "vlm-only",
            "--base-url",
            srv.base_url,
            "--model",
            "vlm",
            "--json",
            env=env,
        )
        assert r.returncode == 0, r.stderr
        sent = json.dumps(srv.requests)
        assert srv.requests and sum(srv.images(i) for i in range(len(srv.requests))) == 1
    assert not any(chunk in sent for chunk in leaked)


# ---------------------------------------------------------------- embedder downloads
@pytest.fixture
def hub_404() -> Iterator[str]:
    """A model hub on 127.0.0.1 that knows no model (every request: 404)."""

    class NotFound(http.server.BaseHTTPRequestHandler):
        def _nf(self) -> None:
            self.send_response(404)
            self.send_header("Content-Length", "0")
            self.end_headers()

        do_GET = do_HEAD = _nf

        def log_message(self, *args: object) -> None:
            pass

    srv = http.server.ThreadingHTTPServer(("127.0.0.1", 0), NotFound)
    threading.Thread(target=srv.serve_forever, daemon=True).start()
    yield f"http://127.0.0.1:{srv.server_address[1]}"
    srv.shutdown()
    srv.server_close()


def _hub_env(tmp_path: Path, endpoint: str) -> dict[str, str]:
    # the CLI no longer forces HF_HUB_OFFLINE: the embedder really tries to download
    env = {"HF_HOME": str(tmp_path / "hf-home"), "HF_ENDPOINT": endpoint, "HF_HUB_OFFLINE": "0"}
    return env | {"TRANSFORMERS_OFFLINE": "0"}


def test_a_model_that_cannot_be_downloaded_leaves_nothing_behind(tmp_path: Path, frames: Path, hub_404: str):
    pytest.importorskip("transformers")
    env = _hub_env(tmp_path, hub_404)
    new = tmp_path / "new" / "deep" / "m.mem"
    line = assert_one_line_error(
        run_cli(
            "ingest", str(frames), "-m", str(new), "--embedder", "hf:openai/clip-vit-base-patch32", env=env
        )
    )
    assert "cannot load 'openai/clip-vit-base-patch32'" in line
    assert not (tmp_path / "new").exists()
    # refused before torch and transformers are imported (seconds of imports for nothing)
    traced = run_cli(
        "ingest",
        str(frames),
        "-m",
        str(new),
        "--embedder",
        "hf:openai/clip-vit-base-patch32",
        env=env,
        python_flags=("-X", "importtime"),
    )
    assert traced.returncode == 2 and not {"torch", "transformers"} & imported(traced.stderr)
    empty = tmp_path / "empty.mem"  # a folder that existed before is kept, and left empty
    empty.mkdir()
    assert_one_line_error(
        run_cli(
            "ingest", str(frames), "-m", str(empty), "--embedder", "hf:openai/clip-vit-base-patch32", env=env
        )
    )
    assert empty.is_dir() and not any(empty.iterdir())


@pytest.mark.slow
def test_no_network_download_failure(tmp_path: Path, frames: Path):
    """The hub unreachable (connection refused; huggingface_hub retries for ~25 s first)."""
    pytest.importorskip("transformers")
    env = _hub_env(tmp_path, "http://127.0.0.1:9")
    new = tmp_path / "m.mem"
    line = assert_one_line_error(
        run_cli(
            "ingest", str(frames), "-m", str(new), "--embedder", "hf:openai/clip-vit-base-patch32", env=env
        )
    )
    assert "cannot load" in line and not new.exists()


# ---------------------------------------------------------------- appending
def test_ingest_again_with_default_flags_appends(tmp_path: Path, frames: Path):
    """The default `--embedder offline` is resolved to the stored full name before comparing."""
    later = tmp_path / "later"
    shutil.copytree(frames, later)
    (later / "poses.csv").write_text(
        "file,t,x,y\n" + "".join(f"frame_{i}.png,{2000 + i},{i},1\n" for i in range(3))
    )
    mem = tmp_path / "m.mem"
    for src, total in ((frames, 3), (later, 6)):
        r = run_cli("ingest", str(src), "-m", str(mem), "--no-ocr", "--json")
        assert r.returncode == 0, r.stderr
        assert json.loads(r.stdout)["memories_total"] == total


def test_appending_the_same_recording_again_does_not_inflate_the_counts(
    forked_cli: ForkedCli, tmp_path: Path, frames: Path
):
    """A second run of the same recording sees the same frames: `info` counts them once, so the
    frames seen, the keyframe ratio and the compression figure stay what one run gave. (The first
    ingest in a fresh interpreter, the rest forked by one driver: `ForkedCli`.)"""
    mem = tmp_path / "m.mem"
    infos = []
    for i in range(3):
        cli = run_cli if i == 0 else forked_cli
        r = cli("ingest", str(frames), "-m", str(mem), "--no-ocr", "--keyframes", "all", "--json")
        assert r.returncode == 0, r.stderr
        infos.append(json.loads(forked_cli("info", "-m", str(mem), "--json").stdout))
        # the ingest report's figure is the one `info` gives (the memory at rest)
        assert json.loads(r.stdout)["compression_vs_raw"] == infos[-1]["compression_vs_raw"]
    assert [len(i["ingests"]) for i in infos] == [1, 2, 3]
    assert {i["frames_seen"] for i in infos} == {3}
    assert {i["raw_video_bytes"] for i in infos} == {3 * 64 * 48 * 3}


# ---------------------------------------------------------------- nothing kept, store unreachable
def test_an_ingest_that_keeps_nothing_fails_and_leaves_no_empty_memory(
    forked_cli: ForkedCli, tmp_path: Path, frames: Path
):
    """(The first ingest of each kind in a fresh interpreter, the repeats forked: `ForkedCli`.)"""
    posed = frames
    stamped = tmp_path / "stamped"  # images named by their time, and a pose track that covers none
    stamped.mkdir()
    for i in range(3):
        Image.new("RGB", (64, 48), (80 * i, 40, 90)).save(stamped / f"{1000 + i}.0.png")
    off = tmp_path / "off.csv"
    off.write_text("t,x,y\n5000,0,0\n5001,1,0\n")
    frames = stamped
    new = tmp_path / "new.mem"
    r = run_cli("ingest", str(frames), "-m", str(new), "--no-ocr", "--poses", str(off))
    line = assert_one_line_error(r)
    assert "no frame of" in line and "the new memory was not kept" in line
    assert "skipped 3: outside pose track" in r.stdout  # the report still says why
    assert not new.exists()
    # every frame already stored is a finished resume, not a failure
    mem = tmp_path / "m.mem"
    for cli in (run_cli, forked_cli):
        r = cli("ingest", str(posed), "-m", str(mem), "--no-ocr", "--json")
        assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout)["kept"] == 0 and json.loads(r.stdout)["skipped"]["already in memory"] >= 1
    # into a memory that holds memories: the same failure, and its memories are untouched
    before = {k: v for k, v in tree(mem).items() if k != "memory.json"}
    r = forked_cli("ingest", str(frames), "-m", str(mem), "--no-ocr", "--poses", str(off))
    line = assert_one_line_error(r, warnings=True)
    assert (
        "names no map: taken to be in the memory's" in r.stderr
    )  # a second recording is said to share the map
    assert "nothing was added" in line and "not kept" not in line
    assert {k: v for k, v in tree(mem).items() if k != "memory.json"} == before


def test_an_unreachable_milvus_server_is_one_line(tmp_path: Path, frames: Path):
    pytest.importorskip("pymilvus")
    import socket

    with socket.socket() as s:  # a port nobody listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    uri = f"milvus://127.0.0.1:{port}"
    home = {"XDG_CONFIG_HOME": str(tmp_path / "home"), "RAVENMEM_TRUSTED_STORES": ""}
    new = tmp_path / "new.mem"
    line = assert_one_line_error(
        run_cli("ingest", str(frames), "-m", str(new), "--no-ocr", "--store", uri, env=home)
    )
    assert f"127.0.0.1:{port}" in line and "cannot connect" in line
    assert not new.exists() and not (tmp_path / "home").exists()  # a failed create trusts nothing
    mem = make_memory(tmp_path / "m.mem", n=2)
    mf = mem / "memory.json"
    mf.write_text(json.dumps(json.loads(mf.read_text()) | {"store": uri}))
    trusted = home | {"RAVENMEM_TRUSTED_STORES": f"milvus://10.0.0.1:19530,{uri}"}
    for args in (["info"], ["search", "--time", "0"]):
        line = assert_one_line_error(run_cli(*args, "-m", str(mem), env=trusted))
        assert "cannot connect" in line


def test_a_manifest_cannot_choose_a_server_the_user_never_gave(
    forked_cli: ForkedCli, tmp_path: Path, frames: Path
):
    """An edited or copied memory.json naming a Milvus server is refused before any connection;
    the user's own trust (create --store, or RAVENMEM_TRUSTED_STORES) lets it through."""
    import socket

    with socket.socket() as listener:  # a server that must never be contacted
        listener.bind(("127.0.0.1", 0))
        listener.listen()
        listener.settimeout(0.2)
        uri = f"milvus://127.0.0.1:{listener.getsockname()[1]}"
        mem = make_memory(tmp_path / "m.mem", n=2)
        mf = mem / "memory.json"
        mf.write_text(json.dumps(json.loads(mf.read_text()) | {"store": uri}))
        home = {"XDG_CONFIG_HOME": str(tmp_path / "home"), "RAVENMEM_TRUSTED_STORES": "milvus://other:1"}
        for args in (["info"], ["search", "--time", "0"], ["ingest", str(frames), "--no-ocr"]):
            line = assert_one_line_error(forked_cli(*args, "-m", str(mem), env=home))
            assert "never gave ravenmem" in line and "RAVENMEM_TRUSTED_STORES" in line
        with pytest.raises(TimeoutError):
            listener.accept()  # nobody connected
    # the list `create` keeps ($XDG_CONFIG_HOME/ravenmem/stores.json): a server there is
    # accepted (and then fails to connect: nothing listens any more)
    f = tmp_path / "home" / "ravenmem" / "stores.json"
    f.parent.mkdir(parents=True)
    f.write_text(json.dumps({"trusted": [uri]}))
    line = assert_one_line_error(forked_cli("info", "-m", str(mem), env=home))
    assert "cannot connect" in line


@pytest.mark.parametrize(
    "opts,needle",
    [
        (["--stride", "0"], "--stride: expected a whole number from 1"),
        (["--fps", "nan"], "--fps: expected a rate > 0"),
        (["--batch-size", "0"], "--batch-size: expected a whole number from 1"),
    ],
)
def test_nonsense_ingest_numbers_are_one_line(
    forked_cli: ForkedCli, tmp_path: Path, frames: Path, opts: list[str], needle: str
):
    new = tmp_path / "m.mem"
    line = assert_one_line_error(forked_cli("ingest", str(frames), "-m", str(new), "--no-ocr", *opts))
    assert needle in line
    assert not new.exists()
