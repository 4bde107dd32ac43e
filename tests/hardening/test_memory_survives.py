"""A memory survives any single input: recovery never wedges, a missing store is refused and
nothing changed, read commands write nothing, outputs never destroy inputs, and `forget` with a
relative time means the same instant when it is run again."""

from __future__ import annotations

import io
import json
from pathlib import Path

import httpx
import numpy as np
import pytest
from PIL import Image

import ravenmem
from ravenmem.types import MemoryRecord, Pose
from tests.cli.helpers import T0, make_memory
from tests.conftest import ColorEmbedder, solid
from tests.hardening.conftest import one_line_error, snapshot
from tests.hardening.runner import Driver, hostile_files
from tests.server.conftest import serve_subprocess, stop


def _still_works(mem: Path, n: int) -> None:
    """The memory opens, searches and takes a write."""
    with ravenmem.open(mem, embedder=ColorEmbedder()) as m:
        assert m.count() == n
        assert len(m.search_time("start", k=100)) == n
        m.add(solid("blue"), Pose(0.0, 0.0), T0 + 999)
        assert m.count() == n + 1


# ---------------------------------------------------------------- recovery never wedges
def test_a_journal_recovery_cannot_act_on_is_set_aside_and_the_memory_opens(tmp_path, driver: Driver):
    mem = make_memory(tmp_path / "m.mem")
    # what a writer left before times were checked at the door (t=1e305): a thumbnail name of
    # 309 digits, too long for the file system, which made every later writer crash
    long_name = f"thumbs/{int(1e305 * 1000):015d}_deadbeef.jpg"
    (mem / "pending-thumbs-0123456789ab.json").write_text(
        json.dumps({"thumbs": [[long_name, "live", 0, 1e305]]})
    )
    (mem / "pending-thumbs-ba9876543210.json").write_text("{half a journal")
    runs = [driver.run(["forget", "-m", str(mem), "--ids", "99", "--json"]) for _ in range(2)]
    for r in runs:  # twice: the second writer finds nothing left to trip over
        assert r["rc"] == 0 and "Traceback" not in str(r["stderr"]), r
    assert str(runs[0]["stderr"]).count("set aside") == 2 and "set aside" not in str(runs[1]["stderr"])
    assert not list(mem.glob("pending-thumbs-*.json"))
    assert sorted(p.name for p in mem.glob("*.aside")) == [
        "pending-thumbs-0123456789ab.json.aside",
        "pending-thumbs-ba9876543210.json.aside",
    ]
    _still_works(mem, 5)


# ---------------------------------------------------------------- a missing store is refused
@pytest.mark.parametrize("how", ["absent", "empty", "absent, only thumbnails left"])
def test_a_memory_whose_store_is_gone_is_refused_and_nothing_changes(tmp_path, driver: Driver, how: str):
    mem = make_memory(tmp_path / "m.mem")
    with ravenmem.open(mem, writable=True) as m:  # a writer's close saves the index and columns
        m.store.stats()
    files = hostile_files(tmp_path / "files")
    assert (mem / "index.faiss").stat().st_size > 0
    store = mem / "store.sqlite"
    if how == "empty":
        store.write_bytes(b"")
    else:
        store.unlink()
    if how.endswith("thumbnails left"):
        (mem / "index.faiss").unlink()
        (mem / "columns.cache").unlink(missing_ok=True)
    before = snapshot(mem)
    for args in (
        ["info", "-m", str(mem)],
        ["search", "-m", str(mem), "--time", "start"],
        ["ingest", str(files / "tum-ok"), "-m", str(mem), "--embedder", "test-color"],
        ["forget", "-m", str(mem), "--ids", "1"],
    ):
        line = one_line_error(driver.run(args))
        assert "store missing; nothing was changed" in line, (args, line)
        assert snapshot(mem) == before, args


# ---------------------------------------------------------------- read commands write nothing
def test_read_commands_change_no_file_in_the_memory(tmp_path, driver: Driver):
    mem = make_memory(tmp_path / "m.mem", n=8)
    assert driver.run(["consolidate", "-m", str(mem), "--budget", "7"])["rc"] == 0  # lifelong.sqlite too
    # caches a writer would save and a reader must only rebuild in RAM
    (mem / "index.faiss").unlink()
    (mem / "columns.cache").unlink(missing_ok=True)
    picture = tmp_path / "query.png"
    Image.fromarray(solid("red")).save(picture)
    before = snapshot(mem)
    reads = [
        ["info", "-m", str(mem)],
        ["info", "-m", str(mem), "--json"],
        ["search", "-m", str(mem), "red"],
        ["search", "-m", str(mem), "red", "--latest"],
        ["search", "-m", str(mem), "--time", "start", "-k", "3"],
        ["search", "-m", str(mem), "--position", "1,2"],
        ["search", "-m", str(mem), "--image", str(picture)],
        ["search", "-m", str(mem), "--like", "2", "--sheet", str(tmp_path / "hits.png")],
        ["ask", "Where is the red thing?", "-m", str(mem), "--offline"],
        ["ask", "When did I see blue?", "-m", str(mem), "--offline", "--json"],
    ]
    for args in reads:
        r = driver.run(args)
        assert r["rc"] == 0, (args, r)
        assert snapshot(mem) == before, args
    assert (tmp_path / "hits.png").is_file()


# ---------------------------------------------------------------- outputs never destroy inputs
def test_a_sheet_is_replaced_only_with_force_and_only_when_ravenmem_drew_it(tmp_path, driver: Driver):
    mem = make_memory(tmp_path / "m.mem")
    sheet = tmp_path / "hits.png"
    assert driver.run(["search", "-m", str(mem), "red", "--sheet", str(sheet)])["rc"] == 0
    first = sheet.read_bytes()
    line = one_line_error(driver.run(["search", "-m", str(mem), "blue", "--sheet", str(sheet)]))
    assert "--force" in line and sheet.read_bytes() == first
    assert driver.run(["search", "-m", str(mem), "blue", "--sheet", str(sheet), "--force"])["rc"] == 0
    assert sheet.read_bytes() != first
    before = snapshot(mem)
    link = tmp_path / "link.png"
    link.symlink_to(mem / "memory.json")  # a link into the memory: never written through
    for target in (link, mem / "memory.json", mem / "thumbs" / "x.png"):
        r = driver.run(["search", "-m", str(mem), "red", "--sheet", str(target), "--force"])
        assert "--sheet" in one_line_error(r)
    assert snapshot(mem) == before
    _still_works(mem, 5)


# ---------------------------------------------------------------- forget: the same instant again
def test_forget_with_a_relative_time_removes_nothing_more_when_run_again(tmp_path, driver: Driver):
    mem = make_memory(tmp_path / "m.mem", n=80)  # 10 s apart from T0
    for _ in range(3):
        r = driver.run(["forget", "-m", str(mem), "--before", "+1s"])
        assert r["rc"] == 0, r
        assert "2023-11-14T22:13:21.000Z" in str(r["stdout"])  # the instant used, printed
        with ravenmem.open(mem) as m:
            assert m.count() == 79  # 49, 18, 0 before: "+1s" was read against what was left
    # the documented example, with the same numbers of this memory: a disc after the first 300 s
    runs = [
        json.loads(
            str(
                driver.run(["forget", "-m", str(mem), "--region", "40,80,30", "--after", "+300", "--json"])[
                    "stdout"
                ]
            )
        )
        for _ in range(2)
    ]
    assert runs[0]["removed"] > 0 and runs[1]["removed"] == 0
    assert runs[0]["after_time"] == runs[1]["after_time"]
    assert ravenmem.open(mem).manifest.span_seen == [T0, T0 + 790]


def test_forget_dry_run_resolves_like_the_real_run_and_writes_nothing(tmp_path, driver: Driver):
    mem = make_memory(tmp_path / "m.mem", n=20)
    before = snapshot(mem)
    dry = json.loads(
        str(driver.run(["forget", "-m", str(mem), "--before", "+45", "--dry-run", "--json"])["stdout"])
    )
    assert snapshot(mem) == before
    real = json.loads(str(driver.run(["forget", "-m", str(mem), "--before", "+45", "--json"])["stdout"]))
    assert dry["removed"] == real["removed"] == 5 and dry["before_time"] == real["before_time"]
    assert np.isclose(real["t_last"], T0 + 40)


# ---------------------------------------------------------------- times stored before the checks
def test_a_memory_holding_absurd_times_from_before_the_checks_still_answers(tmp_path, driver: Driver):
    """A memory an earlier version let `t=-1e12` and `t=1e15` into (every later search and
    `info` failed with "year -29719 is out of range", even after a restart) lists, searches and
    serves them as numbers; only new ones are refused at the door."""
    mem = make_memory(tmp_path / "m.mem")
    with ravenmem.open(mem, writable=True, embedder=ColorEmbedder()) as m:
        vec = np.full((2, m.store.dim), 1 / np.sqrt(m.store.dim), np.float32)
        bad = [MemoryRecord(id=0, t=t, pose=Pose(0.0, 0.0), source="old") for t in (-1e12, 1e15)]
        m.store.add(bad, vec)  # below the door: what the earlier version stored
    for args in (
        ["info", "-m", str(mem)],
        ["info", "-m", str(mem), "--json"],
        ["search", "-m", str(mem), "red", "-k", "7"],
        ["search", "-m", str(mem), "--time", "start", "-k", "7"],
        ["search", "-m", str(mem), "--position", "0,0", "-k", "7", "--json"],
        ["ask", "When did I see red?", "-m", str(mem), "--offline"],
    ):
        r = driver.run(args)
        assert r["rc"] == 0 and "Traceback" not in str(r["stderr"]) + str(r["stdout"]), (args, r)
    listed = json.loads(
        str(driver.run(["search", "-m", str(mem), "--position", "0,0", "-k", "7", "--json"])["stdout"])
    )
    assert "no calendar date" in json.dumps(listed)
    proc, url = serve_subprocess(mem)
    try:
        for path, params in (
            ("/search/text", {"q": "red", "k": 7}),
            ("/search/time", {"t": "start", "k": 7}),
            ("/search/position", {"x": 0, "y": 0, "k": 7}),
        ):
            r = httpx.get(url + path, params=params, timeout=120)
            assert r.status_code == 200, (path, r.text)
        refused = httpx.post(
            url + "/memories",
            data={"x": "1", "y": "1", "t": "1e15"},
            files={"image": ("f.png", _png(), "image/png")},
            timeout=120,
        )
        assert refused.status_code == 400 and "out of range" in refused.json()["error"], refused.text
    finally:
        stop(proc)
    _still_works(mem, 7)


def _png() -> bytes:
    buf = io.BytesIO()
    Image.fromarray(solid("green")).save(buf, format="PNG")
    return buf.getvalue()
