"""Every option of the `ravenmem` command is checked once, by its command's option model
(`ravenmem.cli.options`): numbers carry a range, outputs the output rules."""

from __future__ import annotations

import typing
from pathlib import Path
from typing import Annotated

import pytest

from ravenmem.cli.main import app
from ravenmem.cli.options import OUTPUT, PICTURE, Kind, options_model
from ravenmem.errors import InputError

OUTPUTS = {"out", "png", "sheet", "trace", "nav2"}  # parameters that name a file a command writes
NOT_OUTPUTS = {("demo", "out")}  # a folder the demo fills (its own --overwrite rule)
# `ravenmem eval ...` builds its options from the run's config (cli/eval.py, the eval area)
SKIPPED_GROUPS = {"eval"}


def _commands() -> list[tuple[str, typing.Any]]:
    out = [(c.name or c.callback.__name__, c.callback) for c in app.registered_commands]
    for g in app.registered_groups:
        if g.name in SKIPPED_GROUPS or g.typer_instance is None:
            continue
        out += [(f"{g.name} {c.name}", c.callback) for c in g.typer_instance.registered_commands]
    return out


def _plain(hint: typing.Any) -> tuple[typing.Any, list[typing.Any]]:
    if typing.get_origin(hint) is not Annotated:
        return hint, []
    base, *meta = typing.get_args(hint)
    args = [a for a in typing.get_args(base) if a is not type(None)]
    return (args[0] if args and type(None) in typing.get_args(base) else base), meta


@pytest.mark.parametrize("name,func", _commands(), ids=lambda v: v if isinstance(v, str) else "")
def test_every_number_and_output_of_a_command_has_a_kind(name: str, func: typing.Any) -> None:
    unchecked = []
    for param, hint in typing.get_type_hints(func, include_extras=True).items():
        base, meta = _plain(hint)
        kinds = [m for m in meta if isinstance(m, Kind)]
        if base in (int, float) and not kinds:
            unchecked.append(param)
        output = base is Path and param in OUTPUTS and (name, param) not in NOT_OUTPUTS
        if output and not any(k in (OUTPUT, PICTURE) for k in kinds):
            unchecked.append(param)
    assert unchecked == [], f"{name}: options without a kind in cli.options: {unchecked}"


def test_the_option_model_is_checked_before_the_command_runs() -> None:
    search = next(c.callback for c in app.registered_commands if c.callback.__name__ == "search")
    model = options_model(search.__wrapped__)
    assert model is not None and {"k", "like", "radius", "sheet"} <= set(model.model_fields)
    with pytest.raises(InputError, match=r"^--k: expected a whole number from 1 to 1000, got 0$"):
        search(memory=Path("/nonexistent.mem"), text="red", k=0)  # refused before the memory is opened


@pytest.mark.parametrize("name,func", _commands(), ids=lambda v: v if isinstance(v, str) else "")
def test_every_commands_option_model_builds(name: str, func: typing.Any) -> None:
    """The models are built when a command first runs (not at start): a declaration they
    cannot take must still fail here, not in a user's first run."""
    assert getattr(func, "__checked__", False), name  # wrapped by check_commands
    model = options_model(func.__wrapped__)
    kinds = [
        p
        for p, hint in typing.get_type_hints(func.__wrapped__, include_extras=True).items()
        if any(isinstance(m, Kind) for m in _plain(hint)[1])
    ]
    assert (model is None) == (not kinds) and set(kinds) <= set(model.model_fields if model else ()), name
