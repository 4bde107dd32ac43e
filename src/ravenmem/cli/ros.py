"""`ravenmem ros setup` and `ravenmem ros run`: ravenmem as a ROS 2 node (rclpy, the `ros` extra)."""

from __future__ import annotations

import json
import sys
from typing import Annotated

import typer
from pydantic import Field

from ._console import esc, out_console
from .options import Kind, MemoryOpt

JOBS = Kind("a whole number from 1 to 64", (Field(ge=1, le=64),))

ros_app = typer.Typer(
    help="ROS 2: build the interfaces (setup), run the node (run).",
    no_args_is_help=True,
    add_completion=False,
)


def _say(line: str) -> None:
    sys.stderr.write(line + "\n")


@ros_app.command("setup")
def setup(
    force: Annotated[bool, typer.Option("--force", help="rebuild even when up to date")] = False,
    jobs: Annotated[int, JOBS, typer.Option("--jobs", "-j", help="compile jobs")] = 2,
    json_out: Annotated[bool, typer.Option("--json", help="machine-readable output")] = False,
) -> None:
    """Build ravenmem_msgs (and tf2_msgs, nav2_msgs when they are not installed) into this
    Python environment with cmake: afterwards `from ravenmem_msgs.srv import Ask` works with
    nothing to source. Idempotent."""
    from ..ros.build import setup as build_setup

    done = build_setup(force=force, jobs=jobs, log=_say)
    if json_out:
        sys.stdout.write(json.dumps({"prefix": sys.prefix, "packages": done}) + "\n")
        return
    for name, what in done.items():
        out_console().print(esc(f"{name}: {what}"), highlight=False)


@ros_app.command(
    "run",
    context_settings={"allow_extra_args": True, "ignore_unknown_options": True},
)
def run(
    ctx: typer.Context,
    memory: MemoryOpt,
    create: Annotated[bool, typer.Option("--create", help="create the memory when missing")] = False,
    lifecycle: Annotated[
        bool,
        typer.Option(
            "--lifecycle",
            help="a managed node: the memory opens at configure, frames are taken while active "
            "(lifecycle_msgs ChangeState, e.g. from nav2_lifecycle_manager)",
        ),
    ] = False,
) -> None:
    """Run the ravenmem node until SIGINT/SIGTERM. Every setting is a ROS parameter: give them
    after --ros-args (-p image_topic:=/camera/image_raw, --params-file f.yaml, -r __ns:=/bot1)."""
    from ..ros.run import main as node_main

    own = (
        ["--memory", str(memory)] + (["--create"] if create else []) + (["--lifecycle"] if lifecycle else [])
    )
    argv = own + list(ctx.args)
    node_main(argv)


def register(app: typer.Typer) -> None:
    """Add `ravenmem ros ...` to the main command."""
    app.add_typer(ros_app, name="ros")
