"""A memory's display name: kept in its manifest, checked like every field, set and shown by
`ravenmem name`, shown by `ravenmem info` (the service's page shows it too: test_page_operator)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

import ravenmem
from ravenmem.errors import InputError
from ravenmem.memory.manifest import MANIFEST, Manifest
from tests.cli.helpers import assert_one_line_error, make_memory, run_cli


def test_the_manifest_keeps_a_checked_name() -> None:
    assert Manifest.from_json({"embedder": "e", "dim": 4}).name == ""  # older manifests: none
    assert Manifest.from_json({"embedder": "e", "dim": 4, "name": "Lab 2"}).to_json()["name"] == "Lab 2"
    for bad in (3, "two\nlines", "x" * 201, "tab\there"):
        with pytest.raises(InputError, match="field 'name': expected one line of printable text"):
            Manifest.from_json({"embedder": "e", "dim": 4, "name": bad})


def test_set_name_and_reopen(tmp_path: Path) -> None:
    path = make_memory(tmp_path / "desk.mem")
    with ravenmem.open(path, writable=True) as mem:
        assert mem.name == "desk.mem"
        mem.set_name("  Desk, 2nd floor ")
        with pytest.raises(InputError, match="one line"):
            mem.set_name("a\nb")
    with ravenmem.open(path) as mem:
        assert mem.name == "Desk, 2nd floor" and mem.info()["name"] == "Desk, 2nd floor"


def test_the_name_command(tmp_path: Path) -> None:
    path = str(make_memory(tmp_path / "lab.mem"))
    r = run_cli("name", "--memory", path)
    assert r.returncode == 0 and r.stdout.strip() == "lab.mem (the folder's name: none set)"
    r = run_cli("name", "--memory", path, "Lab, second floor")
    assert r.returncode == 0 and r.stdout.strip() == "Lab, second floor"
    assert json.loads((Path(path) / MANIFEST).read_text())["name"] == "Lab, second floor"
    info = run_cli("info", "--memory", path).stdout
    assert "name  Lab, second floor" in info
    before = (Path(path) / MANIFEST).read_bytes()
    assert "one line of printable text" in assert_one_line_error(run_cli("name", "--memory", path, "a\nb"))
    assert (Path(path) / MANIFEST).read_bytes() == before  # refused before anything was written
    r = run_cli("name", "--memory", path, "", "--json")
    assert json.loads(r.stdout) == {"memory": path, "name": "lab.mem", "set": False}
