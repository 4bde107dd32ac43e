"""The served memory: one `Memory`, its one writer, the event stream and the agent, shared by
every front end (HTTP, the page, MCP, the robot link).

No search logic lives here: searches go through `ravenmem.tools`, questions through the agent's
methods, adds through `LiveWriter`. What this adds is what a long-running process needs: models
loaded once, the results in the one JSON shape (`tools.hit_json`) with images as URLs, and
paths that never leave the memory folder.
"""

from __future__ import annotations

import io
import logging
import threading
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from PIL import Image

from ..agent.ask import AskRequest, AskResult, build_method
from ..agent.ask import ask as agent_ask
from ..agent.base import METHODS, needs_vlm
from ..agent.config import VLMConfig
from ..agent.presets import PRESETS
from ..agent.progress import Progress, ToolStep, watch
from ..agent.schema import Answer
from ..agent.support import Judge
from ..errors import EmptyMemoryError, InputError
from ..ingest.keyframes import KeyframeConfig
from ..memory import Memory
from ..memory.folder import MAP_GRID, MAP_META
from ..memory.manifest import confine
from ..tools import Tool, ToolArgs, hit_json
from ..types import Hit, Intrinsics, MemoryRecord
from .ask import AskArgs, check_calls, check_top_k
from .events import EventBus
from .images import DecodeGate, decode_base64_image
from .live import AddResult, LiveWriter

if TYPE_CHECKING:
    from ..nav.goals import GoalPlan

log = logging.getLogger(__name__)

MAX_TRAJECTORY = 100_000  # points the map may ask for at once
ImageUrl = Callable[[MemoryRecord], str | None]


@dataclass
class ServiceConfig:
    """How the service answers. `method` is the default for questions (None: `raven` when a VLM
    model is configured, else `offline`); `preset`, `top_k` (N or {tool: N}) and `max_tool_calls`
    are defaults a question may override (None: the method's or the preset's own); `vlm` is the
    service's own model endpoint (clients never choose one); sizes and times bound every request."""

    keyframes: KeyframeConfig = field(default_factory=KeyframeConfig)
    method: str | None = None
    vlm: VLMConfig | None = None
    preset: str | None = None
    top_k: int | dict[str, int] | None = None
    max_tool_calls: int | None = None
    max_upload_bytes: int = 16 * 2**20
    max_pixels: int = 40_000_000
    timeout_s: float = 120.0
    body_timeout_s: float = 30.0  # a request body must arrive within this (slow senders: 408)
    decode_budget: int | None = None  # RAM for pictures decoded at once (None: sized to the machine)
    writable: bool = True
    intrinsics: Intrinsics | None = None  # the depth camera of live adds: they update the map
    camera_frame: str = "body"  # live poses are of a body (x forward, z up) or the optical frame

    def __post_init__(self) -> None:
        from ..agent.presets import get_preset

        check_top_k(self.top_k)
        check_calls(self.max_tool_calls)
        get_preset(self.preset)
        if self.max_upload_bytes <= 0 or self.max_pixels <= 0:
            raise InputError("upload size and pixel count must be > 0")
        for name in ("timeout_s", "body_timeout_s"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and 0 < v <= 86_400):
                raise InputError(f"{name} must be a number of seconds from 0 to 86400, got {v!r}")
        if self.decode_budget is not None and self.decode_budget <= 0:
            raise InputError(f"decode_budget must be > 0 bytes, got {self.decode_budget}")
        if self.method is not None:
            METHODS.get(self.method)  # an unknown name is a one-line error now, not on the first question
            if needs_vlm(self.method) and not (self.vlm is not None and self.vlm.configured):
                # as `ravenmem eval`: a default method that cannot answer stops the start, not every question
                raise InputError(
                    f"--method {self.method} needs a VLM and none is configured: give --model and "
                    "--base-url, or set RAVENMEM_VLM_MODEL / RAVENMEM_VLM_BASE_URL"
                )
        if self.camera_frame not in ("body", "optical"):
            raise InputError(f"camera frame must be 'body' or 'optical', got {self.camera_frame!r}")

    @property
    def default_method(self) -> str:
        if self.method:
            return self.method
        return "raven" if self.vlm is not None and self.vlm.configured else "offline"


LIVE_MAP_SAVE_EVERY = 30  # live depth frames between saves of the map (the page and /map read it)


class Service:
    """A memory served to many clients; see the module docstring."""

    def __init__(self, mem: Memory, cfg: ServiceConfig | None = None) -> None:
        self.mem = mem
        self.cfg = cfg or ServiceConfig()
        self.bus = EventBus()
        mapper = None
        if self.cfg.writable and self.cfg.intrinsics is not None:
            from ..nav.mapping import MapBuilder

            mapper = MapBuilder(
                mem.path, self.cfg.intrinsics, self.cfg.camera_frame, save_every=LIVE_MAP_SAVE_EVERY
            )
        self.writer: LiveWriter | None = (
            LiveWriter(mem, self.cfg.keyframes, on_result=self._on_result, mapper=mapper)
            if self.cfg.writable
            else None
        )
        self.gate = DecodeGate(
            self.cfg.decode_budget
        )  # RAM of uploaded pictures decoded at once (503 past it)
        self._traj_lock = threading.Lock()
        self._traj: tuple[int, list[list[float]]] | None = None
        self._map: tuple[int, tuple[bytes, dict[str, Any]]] | None = None
        self._image_url: ImageUrl = lambda rec: None
        self._links: list[Any] = []
        self._judge: Judge | None = None  # text hits' support verdicts (its calibration kept)

    # ---------------------------------------------------------------- lifecycle
    def start(self) -> Service:
        """Take the memory's writer lock (held until `close`) and start the writer thread; a
        read-only service takes no lock and may run beside a writer."""
        if self.writer is not None:
            self.mem.acquire_writer(wait=False)
            self.writer.start()
        return self

    def attach(self, link: Any) -> None:
        """Another front end that lives as long as the service (the robot link): it is told each
        answer that may be used, typed (`on_answer(result)`: an `AskResult`), shown in `/info` under `links` (`describe()`), and closed
        before the writer (`close()`), so the frames it handed over are stored."""
        self._links.append(link)

    def stop_streams(self) -> None:
        """End the open event streams (the server is stopping; listeners reconnect elsewhere)."""
        self.bus.close()

    def warm_up(self) -> None:
        """Load the embedder and run it once, so the first question is as fast as the next
        (every front end that serves calls it before it says it is ready)."""
        emb = self.mem.embedder
        emb.embed_texts(["warm up"])
        if self.cfg.writable:
            emb.embed_images([np.zeros((32, 32, 3), np.uint8)])

    def close(self) -> None:
        """Store what is queued, note the live counts in the manifest, end the streams, close."""
        for link in self._links:
            try:
                link.close()
            except Exception:
                log.exception("closing %r failed", link)
        self.bus.close()
        if self.writer is not None:
            self.writer.close()
            if self.writer.stats.seen:
                try:
                    self.mem.record_ingest(self.writer.report())
                except OSError:
                    log.exception("could not note the live counts in the manifest")
        self.mem.close()

    def set_image_url(self, fn: ImageUrl) -> None:
        """How events name a memory's image (the HTTP app sets its URL)."""
        self._image_url = fn

    # ---------------------------------------------------------------- reading
    def t0(self) -> float:
        try:
            return self.mem.time_span()[0]
        except EmptyMemoryError:
            return 0.0

    def search(self, tool: Tool, args: ToolArgs, k: int, image: np.ndarray | None = None) -> list[Hit]:
        """The tool's hits; a text search's marked supported or not (`ravenmem.agent.support`)."""
        hits = tool.run(self.mem, args, k, image=image)
        query = getattr(args, "query", None)
        if tool.key != "text" or not query:
            return hits
        return self.judge().mark(query, hits)

    def judge(self) -> Judge:
        """The memory's one `Judge`: its decoy calibration serves the search verdicts and the
        offline questions alike (`ask`), made again only when the memory has doubled or halved."""
        with self._traj_lock:
            if self._judge is None:
                self._judge = Judge(self.mem)
            return self._judge

    def rows(self, hits: list[Hit], image_url: ImageUrl) -> list[dict[str, Any]]:
        """Hits in the `--json` shape of the CLI, images as URLs."""
        t0 = self.t0()
        return [hit_json(h, i + 1, t0, image_url) for i, h in enumerate(hits)]

    def record(self, memory_id: int) -> MemoryRecord:
        return self.mem.get([memory_id])[0]  # NotFoundError: HTTP 404

    def record_json(self, rec: MemoryRecord, image_url: ImageUrl) -> dict[str, Any]:
        """One memory in the hit shape, without the fields that only a search gives."""
        row = hit_json(Hit(memory=rec), 0, self.t0(), image_url)
        for key in ("rank", "score", "distance", "ocr_match", "supported"):
            row.pop(key)
        return row

    def image_file(self, rec: MemoryRecord) -> Path | None:
        """The memory's image file when it lies inside the memory folder (never a path outside it:
        a memory built without thumbnails points at the original frames, which are not served)."""
        p = self.mem.image_file(rec)
        if p is None:
            return None
        root = self.mem.path.resolve()
        try:
            real = p.resolve(strict=True)
            real.relative_to(root)
        except (OSError, ValueError):
            return None
        return real if real.is_file() else None

    def trajectory(self, max_points: int = 20_000) -> dict[str, Any]:
        """The path for the map: [id, t, x, y, yaw] per memory, chronological, thinned to at most
        `max_points` by an even stride (the last memory always included)."""
        if isinstance(max_points, bool) or not 2 <= int(max_points) <= MAX_TRAJECTORY:
            raise InputError(f"max_points must be from 2 to {MAX_TRAJECTORY}")
        n = self.mem.count()
        with self._traj_lock:
            if self._traj is None or self._traj[0] != n:
                recs = self.mem.all_records()
                pts = [[r.id, r.t, r.pose.x, r.pose.y, r.pose.yaw] for r in recs]
                self._traj = (len(pts), pts)
            pts = self._traj[1]
        stride = max(1, -(-len(pts) // max_points))
        picked = pts[::stride]
        if pts and picked[-1] is not pts[-1]:
            picked.append(pts[-1])
        return {"count": len(pts), "stride": stride, "fields": ["id", "t", "x", "y", "yaw"], "points": picked}

    def _map_files(self) -> list[Path] | None:
        """The map's two files, or None when either is absent (or a link leading out)."""
        files = [confine(self.mem.path, name) for name in (MAP_META, MAP_GRID)]
        found = [f for f in files if f is not None and f.is_file()]
        return found if len(found) == len(files) else None

    def occupancy_map(self) -> tuple[bytes, dict[str, Any]] | None:
        """The memory's occupancy map (`map.json` + `map.npz`, written by exploration) as a PNG,
        north up, and the rectangle it covers in metres; None when the memory has no map.
        Rendered again only when the map file changes."""
        files = self._map_files()
        if files is None:
            return None
        try:
            stamp = files[1].stat().st_mtime_ns
        except OSError:
            return None
        with self._traj_lock:
            if self._map is not None and self._map[0] == stamp:
                return self._map[1]
        from ..nav.grid import OccupancyGrid
        from ..nav.render import grid_rgb

        try:
            grid = OccupancyGrid.load(self.mem.path)
        except (InputError, OSError, ValueError) as e:
            log.warning("the memory's map cannot be read: %s", e)
            return None
        rgb = np.clip(grid_rgb(grid)[::-1] * 255.0 + 0.5, 0, 255).astype(np.uint8)  # row 0 = north
        buf = io.BytesIO()
        Image.fromarray(rgb).save(buf, "PNG", optimize=True)
        xmin, xmax, ymin, ymax = grid.extent()
        h, w = grid.shape
        meta = {
            "resolution": grid.resolution,
            "shape": [h, w],
            "extent": [xmin, ymin, xmax, ymax],
            # which map this is: how it was made, and of which world when exploration made it
            "kind": grid.kind,
            "env": grid.meta.get("env") if isinstance(grid.meta.get("env"), str) else None,
        }
        with self._traj_lock:
            self._map = (stamp, (buf.getvalue(), meta))
        return self._map[1]

    def info(self) -> dict[str, Any]:
        """`Memory.info()` as a client may see it: the folder's name, not its path on this machine."""
        data = self.mem.info()
        data["path"] = self.mem.path.name
        data["live"] = self.writer.stats.as_dict() if self.writer is not None else None
        data["has_map"] = self._map_files() is not None  # the page asks for /map only then
        data["ask"] = {
            "default_method": self.cfg.default_method,
            "default_preset": self.cfg.preset,
            "presets": sorted(PRESETS),
            "vlm": bool(self.cfg.vlm is not None and self.cfg.vlm.configured),
            "methods": METHODS.names(),
            "needs_vlm": [m for m in METHODS.names() if needs_vlm(m)],  # the page shows them disabled
        }
        if self._links:
            data["links"] = [link.describe() for link in self._links]
        return data

    # ---------------------------------------------------------------- asking
    def ask(
        self,
        args: AskArgs,
        picture: np.ndarray | None = None,
        start: tuple[float, float] | None = None,
        drive: Callable[[dict[str, Any]], dict[str, Any] | None] | None = None,
        progress: Progress | None = None,
    ) -> AskResult:
        """The one way every front end asks (HTTP, MCP, the robot services): answer `args` as
        `ravenmem ask` does (`agent.ask`) with the service's own VLM (what the question leaves
        out comes from the service's defaults, then the preset or the method); with `navigate`,
        plan a path on the memory's map to the answer (from `args.start`, else `start`, the
        robot's latest pose a link knows, else the trajectory's last pose); `drive` (a link's
        NavigateToPose) drives to a goal that may be used. Each tool call, as it ends, goes to
        the event stream (`tool_call`) and to `progress` (`agent.progress.ToolStep`: the ROS 2
        action's feedback). Then publish: every answer to the event stream, the ones that may be
        used to the robot links. The result stays typed; each front end writes its own wire
        format from it (`result_json`, an `Ask_Response`)."""
        image = picture if picture is not None else self.picture_of(args)
        opts = args.to_options(
            self.cfg.default_method,
            vlm=self.cfg.vlm or VLMConfig(),  # the service's model or none: never the environment's
            preset=self.cfg.preset,
            top_k=self.cfg.top_k,
            max_tool_calls=self.cfg.max_tool_calls,
        )
        plan = None
        if args.navigate:
            from ..nav.grid import OccupancyGrid

            grid = OccupancyGrid.load(self.mem.path)  # no map: one line naming how to build one
            where = args.start or start

            def plan(ans: Answer, allow: bool) -> GoalPlan:
                return self.plan(
                    ans, where, allow_unsupported=allow, grid=grid, robot_radius=args.robot_radius
                )

        def step(ev: ToolStep) -> None:
            self.bus.publish("tool_call", {"question": args.question, **ev.as_dict()})
            if progress is not None:
                progress(ev)

        method = build_method(self.mem, opts)
        if self.mem.count() > 0:
            self.judge().lend(method)  # an offline question: the searches' calibration, not a new one
        watch(method, step)
        result = agent_ask(
            self.mem, AskRequest(args.question, opts, image, plan, args.allow_unsupported), method
        )
        if drive is not None and result.goal is not None:
            result.drive = drive(result.goal)  # how the drive went, in the answer
        self.publish(result)
        return result

    def picture_of(self, args: AskArgs) -> np.ndarray | None:
        """The query picture a request names: an upload (decoded under the RAM budget) or a
        stored memory's picture; None for a question without one."""
        if args.image is not None:
            return decode_base64_image(args.image, self.cfg.max_pixels, "image", self.gate)
        if args.image_memory_id is None:
            return None
        img = self.mem.load_image(self.record(args.image_memory_id))
        if img is None:
            raise InputError(f"memory {args.image_memory_id} has no stored picture")
        return img

    def result_json(self, result: AskResult, image_url: ImageUrl) -> dict[str, Any]:
        """The result as `ravenmem ask --json` gives it (evidence images as URLs), with its
        navigation plan and how the drive went when there were any: the one JSON of an answer."""
        data = self.answer_json(result.answer, image_url)
        if result.plan is not None:
            data["navigation"] = result.plan.as_dict()
        if result.drive is not None:
            data["drive"] = result.drive
        return data

    def publish(self, result: AskResult) -> None:
        """Every answer goes to the event stream; only those that may be used (not failed, not
        an unsupported place unless allowed) go to the robot links, typed (`on_answer(result)`)."""
        self.bus.publish("answer", {"answer": self.result_json(result, self._image_url)})
        if result.refusal is not None:
            return
        for link in self._links:
            try:
                link.on_answer(result)
            except Exception:  # a robot link's failure must not fail the question
                log.exception("%r could not take the answer", link)

    # ---------------------------------------------------------------- goals
    def plan(
        self,
        ans: Any,
        start: tuple[float, float] | None = None,
        allow_unsupported: bool = False,
        grid: Any = None,
        robot_radius: float | None = None,
    ) -> GoalPlan:
        """The goal for an answer on the memory's map, as every front end plans it
        (`nav.goals.goal_for`: `POST /ask` with navigate, MCP `ask`, the robot links); a failed
        or unsupported answer is refused there unless `allow_unsupported`."""
        from ..nav.goals import goal_for

        return goal_for(
            ans, self.mem, start, grid=grid, allow_unsupported=allow_unsupported, robot_radius=robot_radius
        )

    def plan_of(self, result: AskResult, start: tuple[float, float] | None = None) -> GoalPlan | None:
        """The plan a robot link drives by: the result's own (asked with navigate), else one made
        now from `start` (the robot's latest pose); None for a result that must not be used."""
        if result.refusal is not None:
            return None
        return result.plan if result.plan is not None else self.plan(result.answer, start)  # type: ignore[return-value]

    def frame_check(self, frame: str) -> str | None:
        """Whether live poses in `frame` (REP 105) may be stored: a memory without a frame yet
        takes it; one in another frame refuses them (the reason, counted by the link)."""
        try:
            self.mem.claim_map(frame_id=frame, what="the live poses")
        except InputError:
            return f"poses in frame {frame!r}, the memory's are in {self.mem.frame_id!r}"
        return None

    def answer_json(self, ans: Answer, image_url: ImageUrl) -> dict[str, Any]:
        """The answer as `ravenmem ask --json` gives it, evidence images as URLs (no paths)."""
        return evidence_json(self.mem, ans, lambda rec, f: image_url(rec), key="image")

    # ---------------------------------------------------------------- writing
    def _on_result(self, res: AddResult, rec: MemoryRecord | None) -> None:
        if rec is None:
            self.bus.publish("skipped", res.as_json())
            return
        self.bus.publish("memory", {"memory": self.record_json(rec, self._image_url)})


def evidence_json(
    mem: Memory, ans: Answer, name: Callable[[MemoryRecord, Path | None], str | None], key: str
) -> dict[str, Any]:
    """The answer as JSON, each evidence memory's picture named under `key` by `name(record,
    file)` (`file`: its picture inside the memory folder, or None), never a stored path as it
    is: the one place the evidence-with-pictures JSON is made (the service names URLs, `ravenmem
    ask` local files). Evidence forgotten since the answer has no picture."""
    data: dict[str, Any] = ans.model_dump(mode="json")
    recs = {r.id: r for r in mem.stored([e.id for e in ans.evidence])}
    for ev in data["evidence"]:
        ev.pop("image_path", None)
        rec = recs.get(ev["id"])
        ev[key] = name(rec, mem.image_file(rec)) if rec is not None else None
    return data


def tool_args(
    key: str,
    query: str | None,
    what: str,
    after: str | None = None,
    before: str | None = None,
    near: list[float] | None = None,
    radius: float | None = None,
) -> dict[str, Any]:
    """The arguments of tool `key` (text, time, position) for a query given as one string, as
    the CLI's options and a `ravenmem_msgs/srv/Search` request give it: the text, the time
    expression, or "x,y[,z]" (`what` names it in a one-line error); `near` (x, y, r) for the
    text tool, `radius` for the position tool. The image tool takes a picture, not a string."""
    args: dict[str, Any] = {"after": after, "before": before}
    if key == "text":
        args["query"] = query
        if near:
            args["near"] = near
    elif key == "time":
        args["time"] = query
    elif key == "position":
        try:
            xyz = [float(v) for v in (query or "").replace(" ", "").split(",")]
        except ValueError:
            xyz = []
        if len(xyz) not in (2, 3) or not all(np.isfinite(xyz)):
            raise InputError(f"{what}: expected 'x,y' or 'x,y,z' in finite metres, got {query!r}")
        args |= {"x": xyz[0], "y": xyz[1], "z": xyz[2] if len(xyz) == 3 else None, "radius": radius}
    else:
        raise InputError(f"{what}: the {key} tool takes a picture, not a query string")
    return args
