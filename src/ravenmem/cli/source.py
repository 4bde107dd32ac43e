"""Where `search`, `info` and `ask` read from, behind one API: a memory folder opened here
(`LocalSource`) or a running `ravenmem serve` (`server.client.ServerClient`), so each command
has one code path and one renderer whatever the source.

Both offer: `info()` (what `ravenmem info --json` prints), `search(tool, call, k, image)` (the
hits in the `--json` shape, `tools.hit_json`, each picture named under `image`: a file here, a
URL there), `ask_json(args, image)` (the answer as `ravenmem ask --json` prints it, its refusal
and exit code), `picture(id)` (a memory's picture bytes, for contact sheets), `t0()` and
`where` (what a sheet's title names).
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Protocol

from ..errors import EmptyMemoryError, NotFoundError
from ..tools import Tool, ToolArgs

AskOutput = tuple[dict[str, Any], str | None, int]  # the answer's JSON, its refusal, the exit code


class Source(Protocol):
    where: str

    def info(self) -> dict[str, Any]: ...

    def search(
        self, tool: Tool, call: ToolArgs, k: int, image: Path | None = None
    ) -> list[dict[str, Any]]: ...

    def ask_json(self, args: Any, image: Path | None = None) -> AskOutput: ...

    def picture(self, memory_id: int) -> bytes | None: ...

    def t0(self) -> float | None: ...


@contextmanager
def open_source(memory: Path | None, server: str | None, **model: Any) -> Iterator[Source]:
    """The source the options name (`--server`, $RAVENMEM_SERVER, or `--memory`); `model`
    (the model's settings, only used by a local VLM method) goes to a local source."""
    from ..server.client import ServerClient, resolve_server

    url = resolve_server(server, memory)
    if url:
        with ServerClient(url) as remote:
            yield remote
        return
    import ravenmem

    assert memory is not None  # resolve_server asked for one of the two
    with ravenmem.open(memory) as mem:
        yield LocalSource(mem, **model)


class LocalSource:
    """A memory opened here; questions answered with the model of the flags, the environment
    and the config file (`model`: VLMConfig settings, `config`, and `options`: the local-only
    method options such as `trace_path`)."""

    def __init__(
        self,
        mem: Any,
        model: dict[str, Any] | None = None,
        config: Path | None = None,
        options: dict[str, Any] | None = None,
    ) -> None:
        self.mem = mem
        self.where = f"memory {Path(mem.path).name}"
        self.model, self.config, self.options = model or {}, config, options or {}

    def info(self) -> dict[str, Any]:
        return dict(self.mem.info())

    def t0(self) -> float | None:
        try:
            return float(self.mem.time_span()[0])
        except EmptyMemoryError:
            return None

    def search(self, tool: Tool, call: ToolArgs, k: int, image: Path | None = None) -> list[dict[str, Any]]:
        from ..imageio import read_image
        from ..tools import hit_json

        hits = tool.run(self.mem, call, k, image=read_image(str(image)) if image is not None else None)
        query = getattr(call, "query", None)
        if tool.key == "text" and query:  # the verdict `ask --offline` declines by, as the service gives it
            from ..agent.support import judged

            hits = judged(self.mem, str(query), hits)
        t0 = self.t0() or 0.0

        def image_file(rec: Any) -> str | None:
            p = self.mem.image_file(rec)
            return str(p) if p else rec.image_path

        return [hit_json(h, i + 1, t0, image_file) for i, h in enumerate(hits)]

    def picture(self, memory_id: int) -> bytes | None:
        try:
            rec = self.mem.get([int(memory_id)])[0]
        except NotFoundError:  # evidence naming a memory that is gone: drawn without its picture
            return None
        p = self.mem.image_file(rec)
        return p.read_bytes() if p is not None else None

    def ask_json(self, args: Any, image: Path | None = None) -> AskOutput:
        """Answer here (`agent.ask`), planning on the memory's map with `args.navigate`."""
        from ..agent import AskRequest, MethodOptions, VLMConfig, ask
        from ..imageio import read_image
        from ..runtime.service import evidence_json

        name = args.method or "raven"
        vlm = None
        if MethodOptions.of(
            name
        ).needs_vlm:  # a VLM method reads the VLM settings (a model-free one never does)
            vlm = VLMConfig.resolve(config_path=self.config, **self.model)
        opts = args.to_options(name, vlm=vlm, **self.options)
        plan = self._planner(args) if args.navigate else None  # no map: one line, before the model
        img = read_image(image) if image is not None else None
        if args.image_memory_id is not None:
            img = self.mem.load_image(self.mem.get([args.image_memory_id])[0])
        result = ask(self.mem, AskRequest(args.question, opts, img, plan, args.allow_unsupported))
        # only pictures inside the memory folder are named (a stored path is never shown as is)
        data = evidence_json(self.mem, result.answer, lambda rec, f: str(f) if f else None, key="image_file")
        if result.plan is not None:
            data["navigation"] = result.plan.as_dict()
        return data, result.refusal, result.exit_code

    def _planner(self, args: Any) -> Any:
        from ..nav.goals import goal_for
        from ..nav.grid import OccupancyGrid

        grid = OccupancyGrid.load(self.mem.path)  # no map: one line naming how to build one

        def plan(ans: Any, allow: bool) -> Any:
            return goal_for(
                ans, self.mem, args.start, robot_radius=args.robot_radius, grid=grid, allow_unsupported=allow
            )

        return plan


def sheet(
    source: Source, rows: list[dict[str, Any]], out: Path, title: list[str], t0: float | None = None
) -> None:
    """The contact sheet of hits or evidence, pictures from the source: one renderer for both."""
    from ..viz.sheet import remote_sheet

    remote_sheet(rows, source.picture, out, title, t0)
