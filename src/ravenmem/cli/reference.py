"""The command reference page (docs/cli.md), made from the `ravenmem` command tree itself: one
section per command with its usage, its description and a table of its options (name, value,
default, help), so that the docs say what `--help` says and cannot drift from it
(`scripts/gen_cli_docs.py` writes it; a test fails when the committed page is out of date).

The rows are click's own help records (what `ravenmem CMD --help` prints), split into columns:
the option's names and value kind, then its help with the trailing `[default: ...; required]`
moved into a column of its own.
"""

from __future__ import annotations

import re
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

import typer

PAGE_HEAD = """# Command reference

Every `ravenmem` command with its options, as `ravenmem COMMAND --help` prints them. This page
is generated from the command tree (`python scripts/gen_cli_docs.py`; a test fails when it is
out of date): the other pages explain what the commands are for and link here for the options.

Exit codes, for every command: 0 success; 1 a command that ran but failed (a FAILED `ask`, no
path for `navigate`); 2 bad input (one `error: ...` line on stderr, nothing written). Every
command has `-h`/`--help`.
"""

_SENTENCE = re.compile(r"(?<!\be\.g)(?<!\bi\.e)\.\s")  # a sentence's end (not "e.g. ")
_EXTRA = re.compile(r"\s+\[([^\[\]]*)\]$")  # click's "  [default: 5; required]" at the end of help


@dataclass(frozen=True)
class Row:
    """One option or argument of a command, as its help page shows it."""

    names: str  # "-k, --k" or "--ocr / --no-ocr" or "SOURCE"
    value: str  # "<int>", "flag", ...
    default: str  # "5", "required", "env RAVENMEM_TOKEN", ""
    help: str


@dataclass(frozen=True)
class Section:
    """One command: its path ("ravenmem eval run"), usage line, description and rows."""

    path: str
    usage: str
    description: str
    rows: list[Row]


def sections(app: typer.Typer, prog: str = "ravenmem") -> list[Section]:
    """Every command of `app` (sub-commands of a group after it), in the order of `--help`.
    The commands are typer's click objects (typer ships its own click: typed `Any` here)."""
    group = typer.main.get_command(app)
    root = typer.Context(group, info_name=prog)
    return list(_walk(group, root))


def _walk(cmd: Any, ctx: typer.Context) -> Iterator[Section]:
    subs = getattr(cmd, "commands", None)
    if subs is None or ctx.parent is not None:  # the root group itself has no section
        yield _section(cmd, ctx)
    if subs is None:
        return
    for name in cmd.list_commands(ctx):
        sub = subs[name]
        if not sub.hidden:
            yield from _walk(sub, typer.Context(sub, info_name=name, parent=ctx))


def _section(cmd: Any, ctx: typer.Context) -> Section:
    pieces = " ".join(cmd.collect_usage_pieces(ctx))
    rows = []
    for param in cmd.get_params(ctx):
        record = param.get_help_record(ctx)
        if record is None or "--help" in param.opts:
            continue
        rows.append(_row(param.param_type_name == "argument", *record))
    return Section(ctx.command_path, f"{ctx.command_path} {pieces}".strip(), _prose(cmd.help or ""), rows)


def _row(argument: bool, names: str, text: str) -> Row:
    """Split a help record ('-k, --k <int>', 'how many  [default: 5]') into columns."""
    value = "flag"
    if "<" in names and names.endswith(">"):
        names, _, kind = names.rpartition(" <")
        value = f"<{kind}"
    if argument:  # click shows "[NAME] <str>" for an optional argument, "NAME <str>" otherwise
        names = names.strip("[]")
    default = ""
    m = _EXTRA.search(text)
    if m is not None:
        text = text[: m.start()]
        parts = []
        for part in m.group(1).split("; "):
            key, _, val = part.partition(": ")
            parts.append({"default": val, "required": "required", "env var": f"env {val}"}.get(key, part))
        default = ", ".join(parts)
    return Row(names, value, default, text.strip())


def _prose(text: str) -> str:
    """A docstring's paragraphs with their lines joined (tables and lists are not used in help)."""
    paras = [" ".join(line.strip() for line in p.splitlines()) for p in re.split(r"\n\s*\n", text.strip())]
    return "\n\n".join(p.replace("\b", "").strip() for p in paras if p.strip())


def _cell(text: str, code: bool = False) -> str:
    """Text safe in Markdown (a table cell): pipes escaped; outside `code spans`, `<` and `*`
    kept as text (not HTML, not emphasis)."""
    if code:
        return "`" + text.replace("|", "\\|") + "`" if text else ""
    spans = text.split("`")
    if len(spans) % 2 == 0:  # an odd number of backticks: no code spans to keep
        spans = ["\\`".join(spans)]
    for i in range(0, len(spans), 2):
        spans[i] = spans[i].replace("<", "&lt;").replace("*", "\\*")
    return "`".join(spans).replace("|", "\\|")


def render(app: typer.Typer, prog: str = "ravenmem") -> str:
    """The whole page (Markdown)."""
    out = [PAGE_HEAD]
    secs = sections(app, prog)
    out.append("| command | what it does |\n|---|---|")
    for s in secs:
        anchor = s.path.replace(" ", "-")
        first = _SENTENCE.split(s.description.split("\n\n", 1)[0], 1)[0].rstrip(".")
        out.append(f"| [`{s.path}`](#{anchor}) | {_cell(first)} |")
    for s in secs:
        out.append(f"\n## {s.path}\n\n```text\n{s.usage}\n```\n")
        if s.description:
            out.append(_cell(s.description) + "\n")
        if s.rows:
            out.append("| option | value | default | what it does |\n|---|---|---|---|")
            for r in s.rows:
                out.append(
                    f"| {_cell(r.names, code=True)} | {_cell(r.value, code=r.value != 'flag')} | "
                    f"{_cell(r.default, code=bool(r.default) and r.default != 'required')} | {_cell(r.help)} |"
                )
    return "\n".join(out).rstrip() + "\n"
