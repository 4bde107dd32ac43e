"""Every option of the `ravenmem` command checked once, in one place, before its command runs.

The kinds of values options take (seconds, megabytes, a count, a temperature, a point of the
map, a picture to write, a config file...) are declared here once, each with its range, as
one line of the table below. A command says which kind an option is in its annotation, next
to typer's declaration, and nothing else:

    timeout: Annotated[float, SECONDS, typer.Option(help="...")] = 120.0

`check_commands(app)` (run once by `ravenmem.cli.main` over every registered command, the
other areas' included) builds each command's typed option model (a pydantic model of its
annotated options, `options_model`) and wraps the command so that the model validates the
options given before the body runs: `nan`, `inf`, a negative or absurd number, a folder where a
file is meant, a file inside a memory folder, a config that is not one, is one line
`error: --timeout: ...` (exit 2), and the command runs on the checked values. Options left out
(None) are not checked; the command's own defaults are.

Outputs (`OUTPUT`, `PICTURE`): never inside a memory folder, never through a symlink, never over
a folder; an existing file is replaced only with `--force` (the `FORCE` option of the same
command), and a picture only over a picture ravenmem wrote (`fsio.is_our_picture`).
"""

from __future__ import annotations

import functools
import inspect
import math
import os
import typing
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any

import typer
from pydantic import (
    AfterValidator,
    BaseModel,
    ConfigDict,
    Field,
    ValidationError,
    ValidationInfo,
    create_model,
)

from ..errors import InputError
from ..fsio import MAX_CONFIG, is_our_picture, read_bounded
from ..memory.protocol import MAX_K
from ..types import MAX_COORD, MAX_ID, RANGES, check_coord

DAY = 86_400.0


@dataclass(frozen=True)
class Kind:
    """One kind of option value: how the error line names what is expected, and the pydantic
    constraints (`Field`, validators) that check it."""

    expected: str
    checks: tuple[Any, ...]


def _num(expected: str, **limits: Any) -> Kind:
    return Kind(expected, (Field(allow_inf_nan=False, **limits),))


# ---------------------------------------------------------------- paths and texts
def _memory_folder_above(p: Path) -> Path | None:
    from ..memory.folder import is_memory

    for folder in [p.parent, *p.parent.parents]:
        if is_memory(folder):
            return folder
    return None


def _output(p: Path, info: ValidationInfo, picture: bool) -> Path:
    """The rules of every file a command writes (see the module docstring)."""
    force = bool((info.context or {}).get("force"))
    if p.is_symlink():
        raise ValueError(f"{p} is a symbolic link; ravenmem never writes through one")
    if p.is_dir():
        raise ValueError(f"{p} is a folder; give a file name")
    full = Path(os.path.abspath(p))
    inside = _memory_folder_above(full)
    if inside is not None:
        raise ValueError(f"{p} lies inside the memory folder {inside}; write outputs elsewhere")
    parent = full.parent
    if not parent.is_dir():
        raise ValueError(f"the folder {parent} does not exist")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise ValueError(f"the folder {parent} is not writable")
    if p.exists():
        if not p.is_file():
            raise ValueError(f"{p} exists and is not a regular file")
        if picture and not is_our_picture(p):
            raise ValueError(f"{p} exists and is not a picture ravenmem wrote; choose another name")
        if not force:
            raise ValueError(f"{p} exists; pass --force to replace it")
    return p


def _output_file(p: Path, info: ValidationInfo) -> Path:
    return _output(p, info, picture=False)


def _picture_file(p: Path, info: ValidationInfo) -> Path:
    return _output(p, info, picture=True)


def _config_file(p: Path) -> Path:
    """A VLM config file: a TOML file of bounded size whose settings `VLMConfig` takes."""
    from ..agent.config import VLMConfig

    read_bounded(p, MAX_CONFIG, "config file")
    try:
        VLMConfig.resolve(config_path=p, env={})
    except InputError as e:
        raise ValueError(f"not a ravenmem config: {e}") from None
    return p


def _pair(text: str) -> tuple[float, float] | None:
    parts = [s for s in text.replace(" ", "").split(",") if s]
    if len(parts) != 2:
        return None
    try:
        return float(parts[0]), float(parts[1])
    except ValueError:
        return None


def _point(text: str) -> str:
    """'x,y' in map metres within the range of `ravenmem.types`."""
    xy = _pair(text)
    if xy is None:
        raise ValueError(f"expected 'x,y' in metres, got {text!r}")
    for v in xy:
        try:
            check_coord(v, "x,y")
        except InputError as e:
            raise ValueError(str(e)) from None
    return text


def _goal(text: str) -> str:
    """A goal: 'x,y' (checked as a point) or what to go to ('the red box')."""
    if not text.strip():
        raise ValueError("the goal is empty")
    return _point(text) if _pair(text) is not None else text


def _top_k(text: str) -> str:
    """N or tool=N,... with every N from 1 to MAX_K."""
    from ..agent.presets import parse_top_k

    try:
        value = parse_top_k(text)
    except InputError as e:
        raise ValueError(str(e).removeprefix("--top-k: ")) from None
    for k in value.values() if isinstance(value, dict) else [value]:
        if not isinstance(k, int) or not 1 <= k <= MAX_K:
            raise ValueError(f"every N must be from 1 to {MAX_K}, got {text!r}")
    return text


def choice(*values: str) -> Kind:
    """One of `values` (a name the code knows): anything else is refused, whether or not the
    command goes on to use it."""

    def check(v: str) -> str:
        if v not in values:
            raise ValueError(f"expected one of {', '.join(values)}, got {v!r}")
        return v

    return Kind("one of " + ", ".join(values), (AfterValidator(check),))


def _named(text: str) -> str:
    if not str(text).strip():
        raise ValueError("must not be empty")
    return text


# ---------------------------------------------------------------- the table
SECONDS = _num("seconds from 0 to 86400", ge=0, le=DAY)  # waits
TIMEOUT = _num("seconds > 0, at most 86400", gt=0, le=DAY)
GAP = _num("seconds > 0, at most 10 years", gt=0, le=3650 * DAY)
MEGABYTES = _num("MiB > 0, at most 65536", gt=0, le=65_536)
PORT = Kind("a port from 0 to 65535", (Field(ge=0, le=65_535),))
K = Kind(f"a whole number from 1 to {MAX_K}", (Field(ge=1, le=MAX_K),))
COUNT = Kind("a whole number from 1 to 1,000,000", (Field(ge=1, le=1_000_000),))
STEPS = Kind("a whole number from 1 to 10,000,000", (Field(ge=1, le=10_000_000),))
TOOL_CALLS = Kind("a whole number from 1 to 20", (Field(ge=1, le=20),))
RETRIES = Kind("a whole number from 0 to 100", (Field(ge=0, le=100),))
SEED = Kind(f"a whole number from 0 to {MAX_ID}", (Field(ge=0, le=MAX_ID),))
MEMORY_ID = Kind(RANGES["id"], (Field(ge=0, le=MAX_ID),))
IMAGE_SIDE = Kind("pixels from 0 (as stored) to 8192", (Field(ge=0, le=8192),))
THUMB_SIZE = Kind("pixels from 0 (off) to 8192", (Field(ge=0, le=8192),))
STRIDE = Kind("a whole number from 1 to 1,000,000", (Field(ge=1, le=1_000_000),))
BATCH = Kind("a whole number from 1 to 4096", (Field(ge=1, le=4096),))
TEMPERATURE = _num("a number from 0 to 2", ge=0, le=2)
SIMILARITY = _num("a cosine from -1 to 1", ge=-1, le=1)
RATE = _num("a rate > 0, at most 1000 per second", gt=0, le=1000)
MEASURE = _num("seconds > 0, at most 600", gt=0, le=600)  # a benchmark's share of time
SYNTHETIC = Kind("a whole number from 100 to 10,000,000", (Field(ge=100, le=10_000_000),))
DISTANCE = _num(f"metres > 0, at most {4 * MAX_COORD:g}", gt=0, le=4 * MAX_COORD)
SPAN = Kind(f"metres > 0 (inf: no limit), at most {4 * MAX_COORD:g} when finite", (Field(gt=0),))
ROBOT_RADIUS = _num("metres from 0 to 10", ge=0, le=10)
OFFSET = _num(f"metres from 0 to {4 * MAX_COORD:g}", ge=0, le=4 * MAX_COORD)  # a distance that may be 0
CELL_SIZE = _num("metres from 0.001 to 10", ge=0.001, le=10)
ANGLE = _num("degrees from 0 to 360", ge=0, le=360)
DEPTH_SCALE = _num("units per metre > 0, at most 1e6", gt=0, le=1e6)
POINT = Kind("'x,y' in metres", (AfterValidator(_point),))
GOAL = Kind("'x,y' in metres or what to go to", (AfterValidator(_goal),))
TOP_K = Kind(f"N or tool=N,... (N from 1 to {MAX_K})", (AfterValidator(_top_k),))
CONFIG = Kind("a ravenmem config file", (AfterValidator(_config_file),))
OUTPUT = Kind("a file to write", (AfterValidator(_output_file),))
PICTURE = Kind("a picture to write", (AfterValidator(_picture_file),))
NAME = Kind("a non-empty value", (AfterValidator(_named),))  # a name or spec: '' is refused

Force = Annotated[bool, typer.Option("--force", help="replace an output file that exists")]


def memory_path(text: str) -> Path:
    """A memory folder as given: an empty one ('') is refused (it would mean the current folder)."""
    if not text.strip():
        raise typer.BadParameter("must not be empty (give the memory folder; '.' for this one)")
    return Path(text)


# the memory a command reads or writes, declared once for every command
MemoryOpt = Annotated[Path, typer.Option("--memory", "-m", help="memory folder", parser=memory_path)]
MemoryOrServerOpt = Annotated[
    Path | None, typer.Option("--memory", "-m", help="memory folder (or --server)", parser=memory_path)
]


# ---------------------------------------------------------------- the model of a command
def _kinds(func: Callable[..., Any]) -> dict[str, tuple[Any, Kind, str]]:
    """name -> (value type without None, kind, how the user writes the option) for every
    parameter whose annotation carries a `Kind`."""
    out: dict[str, tuple[Any, Kind, str]] = {}
    for name, hint in typing.get_type_hints(func, include_extras=True).items():
        if typing.get_origin(hint) is not Annotated:
            continue
        base, *meta = typing.get_args(hint)
        kind = next((m for m in meta if isinstance(m, Kind)), None)
        if kind is None:
            continue
        args = [a for a in typing.get_args(base) if a is not type(None)]
        if typing.get_origin(base) in (typing.Union, getattr(__import__("types"), "UnionType", None)):
            base = args[0]
        if typing.get_origin(base) is list:
            base = list[Annotated[(typing.get_args(base)[0], *kind.checks)]]  # type: ignore[misc]
        else:
            base = Annotated[(base, *kind.checks)]  # type: ignore[misc]
        out[name] = (base, kind, _flag(name, meta))
    return out


def _flag(name: str, meta: list[Any]) -> str:
    """`--max-upload-mb` for max_upload_mb (or the first long name typer was given); an
    argument's name in capitals."""
    for m in meta:
        decls = list(getattr(m, "param_decls", None) or ())
        default = getattr(m, "default", None)
        if isinstance(default, str) and default.startswith("--"):  # typer.Option("--from") in Annotated
            decls.insert(0, default)
        if type(m).__name__ == "ArgumentInfo":
            return name.upper()
        long = [d for d in decls if isinstance(d, str) and d.startswith("--")]
        if long:
            return long[0].split("/")[0]
    return "--" + name.replace("_", "-")


def options_model(func: Callable[..., Any]) -> type[BaseModel] | None:
    """The typed option model of a command: one optional field per annotated option (None:
    not given, not checked); None when the command has no such option."""
    kinds = _kinds(func)
    if not kinds:
        return None
    fields: dict[str, Any] = {name: (base | None, None) for name, (base, _, _) in kinds.items()}
    return create_model(  # type: ignore[call-overload, no-any-return]
        f"{func.__name__}_options", __config__=ConfigDict(arbitrary_types_allowed=True), **fields
    )


def checked(func: Callable[..., Any]) -> Callable[..., Any]:
    """`func` with its options validated by its option model before it runs (see the module
    docstring). The model is built when the command first runs, not when the command line is
    built: `ravenmem search` does not pay for the models of options it was not given."""
    if getattr(func, "__checked__", False):
        return func
    sig = inspect.signature(func)

    @functools.cache
    def model_and_kinds() -> tuple[type[BaseModel] | None, dict[str, tuple[Any, Kind, str]]]:
        return options_model(func), _kinds(func)

    @functools.wraps(func)
    def run(*args: Any, **kwargs: Any) -> Any:
        model, kinds = model_and_kinds()
        if model is None:  # a command with no annotated option runs as it is
            return func(*args, **kwargs)
        bound = sig.bind_partial(*args, **kwargs)
        given = {n: bound.arguments.get(n) for n in kinds}
        try:
            ok = model.model_validate(given, context={"force": bound.arguments.get("force", False)})
        except ValidationError as e:
            raise InputError(_message(e, kinds, given)) from None
        for name in kinds:
            if given[name] is not None:
                bound.arguments[name] = getattr(ok, name)
        return func(*bound.args, **bound.kwargs)

    run.__checked__ = True  # type: ignore[attr-defined]
    return run


def _message(e: ValidationError, kinds: dict[str, tuple[Any, Kind, str]], given: dict[str, Any]) -> str:
    """The first error as one line: the option as the user wrote it, what it takes, the value."""
    err = e.errors()[0]
    name = str(err["loc"][0]) if err["loc"] else ""
    _, kind, flag = kinds.get(name, (None, Kind("a valid value", ()), name))
    value = given.get(name)
    if err["type"] == "value_error":
        why = str(err["msg"]).removeprefix("Value error, ")
        return f"{flag}: {why}"
    shown = str(value) if isinstance(value, Path) else repr(value)
    if isinstance(value, float) and not math.isfinite(value):
        shown = str(value)
    return f"{flag}: expected {kind.expected}, got {shown}"


def check_commands(app: typer.Typer) -> None:
    """Wrap every command of `app` (and of its sub-apps) in `checked`; run once, after every
    area registered its commands and before typer builds the command line."""
    for info in app.registered_commands:
        if info.callback is not None:
            info.callback = checked(info.callback)
    for group in app.registered_groups:
        if group.typer_instance is not None:
            check_commands(group.typer_instance)
