"""The hostile-input table (`cases.py`) on the product: command lines in their own processes,
requests to a real `ravenmem serve`, tool calls through the `mcp` client; one service and one
command driver for the whole table. Every case must be refused in one line naming the problem,
and afterwards both memories must open, search and accept writes, holding what they held."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest

pytest.importorskip("fastapi", reason="the service needs the serve extra: pip install 'ravenmem[serve]'")
pytest.importorskip("mcp", reason="the service needs the serve extra: pip install 'ravenmem[serve]'")

from tests.hardening.cases import CASES, Case  # noqa: E402
from tests.hardening.runner import Run, check_intact, run_table, session  # noqa: E402


@pytest.fixture(scope="module")
def table(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Run]:
    with session(Path(tmp_path_factory.mktemp("hostile"))) as run:
        run_table(run)
        yield run


@pytest.mark.parametrize("case", CASES, ids=lambda c: c.name)
def test_case_is_refused_in_one_line(table: Run, case: Case) -> None:
    outcome, seen = table.outcomes[case.name]
    assert outcome == "clear", f"{outcome} (expected one line naming {case.expect!r}): {seen}"


def test_the_memories_survive_the_table(table: Run) -> None:
    assert check_intact(table) == []
