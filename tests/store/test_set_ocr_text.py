"""The embedded store changes a stored memory's OCR text in place (`TextStore`): the text search
sees the new text at once and after reopening, and forgets the old one."""

from __future__ import annotations

from pathlib import Path

import pytest

from ravenmem.errors import InputError
from ravenmem.store import open_store
from ravenmem.store.base import TextStore
from tests.store.store_helpers import make_records, robot_stream


def test_set_ocr_text_replaces_the_text_the_search_sees(tmp_path: Path) -> None:
    recs = make_records(6)
    for r in recs:
        r.ocr_text = ""
    recs[0].ocr_text = "Room 101"
    store = open_store(str(tmp_path / "mem"), 16)
    try:
        assert isinstance(store, TextStore)
        ids = store.add(recs, robot_stream(6, 16))
        assert [i for i, _ in store.search_text("room", 5)] == [ids[0]]
        # ids[0]: its text replaced; ids[1]: text where there was none; 10**9: not stored (ignored)
        assert store.set_ocr_text([ids[0], ids[1], 10**9], ["Fire Exit", "Room 202", "ghost"]) == 2
        assert [r.ocr_text for r in store.get(ids[:2])] == ["Fire Exit", "Room 202"]
        assert [i for i, _ in store.search_text("room", 5)] == [ids[1]]  # 101 is forgotten
        assert [i for i, _ in store.search_text("exit", 5)] == [ids[0]]
        assert store.search_text("ghost", 5) == []
        with pytest.raises(InputError, match="2 ids but 1 texts"):
            store.set_ocr_text(ids[:2], ["one"])
    finally:
        store.close()
    store = open_store(str(tmp_path / "mem"), 16)
    try:
        assert [i for i, _ in store.search_text("exit", 5)] == [ids[0]]
        assert [i for i, _ in store.search_text("room", 5)] == [ids[1]]
    finally:
        store.close()
