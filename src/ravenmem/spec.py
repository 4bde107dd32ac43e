"""The one `KEY=VALUE` spec parser, on the ground floor: every option that takes a spec
(`--keyframes fps=2,min_rotation=10deg`, `--zenoh image=camera,pose=odom`, `--top-k
text=30,time=200`, `--pos-threshold real_world=3`, `--embedder offline:tiles=4:res=224`,
`--option KEY=VALUE`) splits and checks it here, and converts the values itself.

The rules, stated once: parts are separated by `sep` (blank parts are skipped), a part is
`key=value` with a non-empty key (and, unless `empty_value`, a non-empty value), keys are
stripped, a key outside `known` (when given) is refused naming the known ones, and a key given
twice is refused (unless `repeat`: the last wins). Every refusal is one `InputError` line that
starts with `what`, the option as the user wrote it.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence

from .errors import InputError

NOT_A_PAIR = "{what}: {part!r} is not key=value (keys: {keys}{hint})"


def parts(text: str, sep: str = ",") -> list[str]:
    """The non-blank parts of `text`, stripped."""
    return [p.strip() for p in text.split(sep) if p.strip()]


def split_pair(part: str, empty_value: bool = False) -> tuple[str, str] | None:
    """(key, value) of `key=value`, both stripped; None when `part` is not one."""
    key, eq, value = (s.strip() for s in part.partition("="))
    if not eq or not key or (not value and not empty_value):
        return None
    return key, value


def pairs(
    spec: str | Iterable[str],
    what: str,
    *,
    sep: str = ",",
    known: Sequence[str] | None = None,
    hint: str = "",
    bad: str = NOT_A_PAIR,
    repeat: bool = False,
    empty_value: bool = False,
) -> dict[str, str]:
    """{key: value} of a spec (a string split on `sep`, or its parts already split) by the rules
    of the module docstring. `bad` words the error for a part that is not a pair (fields:
    `what`, `part`, `keys`, `hint`)."""
    items = parts(spec, sep) if isinstance(spec, str) else [p.strip() for p in spec if p.strip()]
    keys = ", ".join(known) if known is not None else "any"
    out: dict[str, str] = {}
    for part in items:
        kv = split_pair(part, empty_value)
        if kv is None:
            raise InputError(bad.format(what=what, part=part, keys=keys, hint=hint))
        key, value = kv
        if known is not None and key not in known:
            raise InputError(f"{what}: unknown key {key!r}; choose from {keys}")
        if key in out and not repeat:
            raise InputError(f"{what}: {key} is given twice")
        out[key] = value
    return out
