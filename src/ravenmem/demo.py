"""`ravenmem demo`: a simulated robot explores worlds while building its memory (Phase I), then
is asked "where did you see this?" about objects it passed, answers from the memory and drives
to each answer with A* on the map it built (Phase II). Offline, on CPU.

The first world (`synthetic:gallery`, `sim/gallery.py`) is one the offline embedder can
perceive: pillars showing real photographs (a keyboard, a monitor, a person, an office chair, a
book, a game controller) in four rooms, asked about with questions written before the demo was
first run on it and kept fixed. The Freedoom maps follow as the harder worlds: the offline
embedder knows nothing of Doom's sprites.

Four ways to answer the same questions, so that what works and what does not is visible:

- `image`: a picture of the object (rendered by the simulator from a place the robot never
  stored a keyframe at) through the image tool (`TOOLS["search_image"]`), top hit;
- `oracle`: oracle perception, the simulator's ground-truth labels in place of the image
  embedder (`ravenmem.robot.oracle`): the upper bound of memory + agent + planner;
- `text`: the question as text, answered by the offline reasoner over the offline embedder
  (which knows the gallery's photographs, not Doom's sprites);
- `random`: a random memory's pose, the floor.

Queries ask about object kinds the robot saw at least once, with an instance within 2 m of
floor a robot can reach (simulator ground truth; in the gallery every kind, in a fixed order).
An answer that is a memory (image, text, random) is driven to that memory's pose (where the
robot stood when it saw the thing); the oracle's to where its label box and depth put the
object. Every query starts from the map's start; success is the
robot ending within `success_radius` metres of the nearest true instance after driving. SR is
printed with its 95 % Wilson interval (a handful of questions per world: the intervals are
wide). Maps, seeds and start times are fixed, so results reproduce.

    from ravenmem.demo import DemoConfig, run_demo
    report = run_demo(DemoConfig(out="ravenmem-demo"))
    print(report.table())
"""

from __future__ import annotations

import copy
import json
import math
import re
import shutil
import statistics
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from PIL import Image

from .errors import InputError
from .fsio import atomic_write_json
from .nav.render import MapLayers, draw_map
from .progress import Eta
from .robot.explore import ExploreConfig
from .robot.mission import explore_into, navigate_to
from .robot.oracle import oracle_memory
from .robot.pictures import query_picture
from .sim.base import SceneObject, create_env
from .sim.groundtruth import reachable_floor
from .sim.queries import DemoQuery, make_queries
from .tools import TOOLS

DEFAULT_MAPS = ("synthetic:gallery", "vizdoom:freedoom2/MAP02", "vizdoom:freedoom1/E1M2")
GALLERY = "synthetic:gallery"
# keyframe spacing (metres, radians) per world where it differs from the config's: the gallery's
# photographs are recognised from a few metres, so its robot keeps a memory every metre / 30 degrees
KEYFRAMES: dict[str, tuple[float, float]] = {GALLERY: (1.0, math.radians(30.0))}
METHODS = ("image", "oracle", "text", "random")
LABELS = {
    "image": "image query",
    "oracle": "oracle perception",
    "text": "text (offline)",
    "random": "random memory",
}
EXPLAIN = {
    "image": "a picture of the object, rendered by the simulator from a place the robot never "
    "stored, through the image tool (offline embedder), top hit",
    "oracle": "the simulator's ground-truth labels as the perception (an upper bound: the real "
    "memory, agent and planner with perfect perception)",
    "text": "the question as text, offline reasoner over the offline embedder",
    "random": "a random memory (the floor)",
}
LOOKED_AT = "an answer that is a memory is driven to its pose, where the robot stood when it saw the thing"
Answer = tuple[bool, tuple[float, float] | None, str]  # found, position, note


@dataclass
class DemoConfig:
    """Demo settings. `text_method` / `oracle_method` name the agent (a `METHODS` registry
    name) that answers text queries over the real / the oracle memory."""

    maps: list[str] = field(default_factory=lambda: list(DEFAULT_MAPS))
    out: str = "ravenmem-demo"
    steps: int = 3000
    embedder: Any = "offline"  # a spec, or an Embedder instance
    methods: tuple[str, ...] = METHODS
    text_method: str = "offline"
    oracle_method: str = "offline"
    queries: int = 8
    success_radius: float = 3.0
    drive_steps: int = 800
    keyframe_dist: float = 2.0
    keyframe_turn: float = math.radians(45.0)
    overwrite: bool = False
    start_time: float = 1.7e9
    seed: int = 0
    png: bool = True
    pictures: str = "view"  # image queries: "view" (rendered elsewhere) or "sprite" (from the WAD)

    def __post_init__(self) -> None:
        bad = [m for m in self.methods if m not in METHODS]
        if bad or not self.methods:
            raise InputError(f"demo: unknown method(s) {bad}; choose from {', '.join(METHODS)}")
        if not self.maps:
            raise InputError("demo: no maps given")
        if self.pictures not in ("view", "sprite"):
            raise InputError(f"demo: pictures must be 'view' or 'sprite', got {self.pictures!r}")
        if self.queries < 1 or self.steps < 1 or self.success_radius <= 0:
            raise InputError("demo: queries and steps must be >= 1, success_radius > 0")


@dataclass
class Attempt:
    """One query answered by one method and driven to."""

    method: str
    kind: str
    query: str
    found: bool
    answer: tuple[float, float] | None
    answer_err: float  # metres from the answer to the nearest true instance (inf if none)
    final_dist: float  # metres from where the robot stopped to the nearest true instance
    success: bool
    path_m: float  # planned A* path length from the start (inf when no plan)
    driven_m: float
    note: str = ""


@dataclass
class MapRun:
    """One map: exploration, then every method on every query."""

    env: str
    folder: str
    memories: int
    steps: int
    stop_reason: str
    explored_m2: float
    coverage: float | None
    queries: list[str] = field(default_factory=list)
    attempts: list[Attempt] = field(default_factory=list)
    random_expected: float = 0.0
    png: str | None = None
    seconds: float = 0.0

    def of(self, method: str) -> list[Attempt]:
        return [a for a in self.attempts if a.method == method]


@dataclass
class DemoReport:
    maps: list[MapRun]
    methods: tuple[str, ...]
    success_radius: float
    out: str
    wall_seconds: float = 0.0

    def attempts(self, method: str) -> list[Attempt]:
        return [a for m in self.maps for a in m.of(method)]

    def sr(self, method: str) -> float:
        a = self.attempts(method)
        return sum(x.success for x in a) / len(a) if a else 0.0

    def table(self) -> str:
        """What the CLI prints: per map a row per object, then SR, answer error and path length
        per method; then the totals."""
        r = self.success_radius
        lines = [
            f"ravenmem demo: explore, remember, answer 'where did you see the ...?', drive there with A* "
            f"(success = robot ends within {r:g} m of a true instance)",
        ]
        lines += [f"  {LABELS[m]:<18} = {EXPLAIN[m]}" for m in self.methods]
        w = 20
        for run in self.maps:
            cov = f"{100 * run.coverage:.0f}% of the reachable floor, " if run.coverage is not None else ""
            lines += [
                "",
                f"{run.env}: explored {cov}{run.explored_m2:.0f} m^2 in {run.steps} steps ({run.stop_reason}); "
                f"{run.memories} memories; {run.seconds:.0f} s",
                f"{'object':<26}" + "".join(f"{LABELS[m]:>{w}}" for m in self.methods),
                f"{'':<26}" + "".join(f"{'err m  ok  path m':>{w}}" for _ in self.methods),
            ]
            for q in run.queries:
                cells = []
                for m in self.methods:
                    a = next((x for x in run.of(m) if x.query == q), None)
                    cells.append(_cell(a))
                lines.append(f"{q[:26]:<26}" + "".join(f"{c:>{w}}" for c in cells))
            lines.append(_summary_row("SR [95% interval]", run.attempts, self.methods, w, _sr_cell))
            lines.append(_summary_row("median answer error m", run.attempts, self.methods, w, _err_cell))
            lines.append(_summary_row("mean A* path m", run.attempts, self.methods, w, _path_cell))
            lines.append(
                f"{'':<26}random memory, expected SR of the answer position: {100 * run.random_expected:.0f}%"
            )
            if any(_DECLINED_CELL.match(a.note) for a in run.attempts if not a.found):
                lines.append(
                    f"{'':<26}'a < thr b': declined, the best match's support a is under the threshold b "
                    "that things not there reach (ravenmem ask --offline explains one)"
                )
        lines.append("")
        for run in self.maps:
            row = ", ".join(f"{LABELS[m]} {sr_text(run.of(m))}" for m in self.methods)
            lines.append(f"SR on {run.env}: {row}")
        tot = ", ".join(f"{LABELS[m]} {sr_text(self.attempts(m))}" for m in self.methods)
        lines.append(f"SR over {len(self.maps)} maps: {tot}")
        lines.append(f"(SR in %, [95% Wilson interval]; {LOOKED_AT})")
        lines.append(
            f"wall time {self.wall_seconds:.0f} s; outputs in {self.out}/ (memories, maps, query pictures, demo.json)"
        )
        if self.maps:
            lines.append(f"look around a memory: ravenmem serve --memory {self.maps[0].folder}/memory")
        return "\n".join(lines)

    def as_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["sr"] = {m: self.sr(m) for m in self.methods}
        d["labels"] = {m: LABELS[m] for m in self.methods}
        return json.loads(json.dumps(d, default=str, allow_nan=True).replace("Infinity", "null"))


def _cell(a: Attempt | None) -> str:
    if a is None:
        return "-"
    if not a.found:
        return a.note or "not found"
    path = f"{a.path_m:6.1f}" if math.isfinite(a.path_m) else "     -"
    return f"{a.answer_err:5.1f} {'yes' if a.success else ' no'} {path}"


def wilson(k: int, n: int, z: float = 1.96) -> tuple[float, float]:
    """The Wilson score interval of a rate k/n (95 % for z = 1.96): unlike the normal
    approximation it stays inside [0, 1] and means something at 0/n, n/n and small n."""
    if n == 0:
        return (0.0, 1.0)
    p = k / n
    mid = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    return (max(0.0, mid - half), min(1.0, mid + half))


def sr_text(a: list[Attempt]) -> str:
    """'4/6 67% [30-90]': successes, rate and its 95 % Wilson interval in %."""
    k, n = sum(x.success for x in a), len(a)
    lo, hi = wilson(k, n)
    return f"{k}/{n} {100 * k / max(1, n):.0f}% [{100 * lo:.0f}-{100 * hi:.0f}]"


def _sr_cell(a: list[Attempt]) -> str:
    return sr_text(a)


def _err_cell(a: list[Attempt]) -> str:
    e = [x.answer_err for x in a if x.found and math.isfinite(x.answer_err)]
    return f"{statistics.median(e):.1f}" if e else "-"


def _path_cell(a: list[Attempt]) -> str:
    p = [x.path_m for x in a if math.isfinite(x.path_m)]
    return f"{statistics.mean(p):.1f}" if p else "-"


_DECLINED = re.compile(r"declined: best support (-?[\d.]+) under the threshold (-?[\d.]+)")


_DECLINED_CELL = re.compile(r"-?[\d.]+ < thr -?[\d.]+$")


def _declined(notes: list[str]) -> str:
    """A table cell for an answer the method declined: the offline reasoner's best support
    under its threshold ('0.189 < thr 0.354'), else 'not found'."""
    for n in notes:
        m = _DECLINED.match(n)
        if m:
            return f"{float(m[1]):.3f} < thr {float(m[2]):.3f}"
    return "not found"


def _summary_row(
    name: str, attempts: list[Attempt], methods: tuple[str, ...], w: int, fmt: Callable[[list[Attempt]], str]
) -> str:
    return f"{name:<26}" + "".join(f"{fmt([a for a in attempts if a.method == m]):>{w}}" for m in methods)


def _prepare_out(cfg: DemoConfig, say: Callable[[str], None]) -> Path:
    """The folder this run writes: `cfg.out`; when that exists, `--overwrite` replaces it (only a
    demo's own folder, one with `demo.json`), otherwise the run goes to the first free
    `<out>-2`, `<out>-3`, ... so that running the demo again never fails nor touches the last
    run's results."""
    out = Path(cfg.out)
    if out.exists() and cfg.overwrite:
        if not (out / "demo.json").exists() and any(out.iterdir()):
            raise InputError(f"{out} was not written by the demo (no demo.json); refusing to delete it")
        shutil.rmtree(out)
    elif out.exists():
        n = 2
        while out.with_name(f"{out.name}-{n}").exists():
            n += 1
        new = out.with_name(f"{out.name}-{n}")
        say(
            f"{out} already exists (an earlier run's results stay there); this run writes {new} (--overwrite replaces {out})"
        )
        out = new
    out.mkdir(parents=True)
    return out


def run_demo(cfg: DemoConfig | None = None, progress: Callable[[str], None] | None = None) -> DemoReport:
    """Run both phases on every map; write the memories, maps, query pictures and `demo.json`
    into `cfg.out`, or `<out>-2`, ... when that exists (and nothing else anywhere)."""
    cfg = cfg or DemoConfig()
    say = progress or (lambda _m: None)
    t0 = time.perf_counter()
    out = _prepare_out(cfg, say)
    report = DemoReport([], tuple(cfg.methods), cfg.success_radius, str(out))
    for i, spec in enumerate(cfg.maps):
        say(f"map {i + 1}/{len(cfg.maps)}: {spec}")
        report.maps.append(_run_map(cfg, spec, out, say))
        report.wall_seconds = time.perf_counter() - t0
        atomic_write_json(out / "demo.json", report.as_dict(), indent=1)
    return report


def _run_map(cfg: DemoConfig, spec: str, out: Path, say: Callable[[str], None]) -> MapRun:
    import ravenmem

    t0 = time.perf_counter()
    env = create_env(spec, start_time=cfg.start_time)
    try:
        folder = out / env.name.split(":", 1)[-1].replace("/", "_")
        mem = ravenmem.create(folder / "memory", embedder=cfg.embedder, ocr=False)
        mem.set_name(f"demo: {env.name.split(':', 1)[-1]}")  # every demo memory's folder is 'memory'
        say(f"{env.name}, phase I: exploring for up to {cfg.steps} steps")
        kf_dist, kf_turn = KEYFRAMES.get(env.name, (cfg.keyframe_dist, cfg.keyframe_turn))
        ecfg = ExploreConfig(steps=cfg.steps, keyframe_dist=kf_dist, keyframe_turn=kf_turn)
        grid, rep = explore_into(env, mem, ecfg, progress=say)
        objects = env.objects()
        kind_of = {o.id: o.kind for o in objects}
        seen = {i for vis in rep.keyframes.values() for i in vis} & _reachable(
            env, objects, cfg.success_radius
        )
        queries = make_queries(objects, seen, cfg.queries, kinds=_fixed_kinds(env.name, objects, seen))
        cov = rep.coverage[-1] if rep.coverage else (0, 0.0, 0.0, None)
        run = MapRun(
            env=env.name,
            folder=str(folder),
            memories=mem.count(),
            steps=rep.steps,
            stop_reason=rep.stop_reason,
            explored_m2=float(cov[2]),
            coverage=cov[3],
            queries=[q.phrase for q in queries],
        )
        recs = mem.all_records()
        if queries and recs:
            spots = [(r.pose.x, r.pose.y) for r in recs]
            run.random_expected = sum(
                sum(q.nearest(x, y) <= cfg.success_radius for x, y in spots) / len(spots) for q in queries
            ) / len(queries)
        say(f"{env.name}, phase II: preparing {len(cfg.methods)} ways to answer {len(queries)} queries")
        answerers = _answerers(cfg, env, grid, mem, rep, objects, kind_of, queries, folder, say)
        layers = MapLayers(
            trajectory=list(rep.trajectory),
            start=rep.trajectory[0] if rep.trajectory else None,
            memories=[(r.pose.x, r.pose.y) for r in recs],
            truths=[(q.phrase, x, y) for q in queries for x, y in q.instances],
        )
        say(
            f"{env.name}, phase II: {len(queries)} queries x {len(answerers)} ways to answer, each driven with A*"
        )
        eta = Eta(say, "  phase II, answered and driven", len(queries) * len(answerers))
        for method, ask in answerers.items():
            for q in queries:
                run.attempts.append(_attempt(cfg, env, grid, method, q, ask(q), layers))
                eta.update(len(run.attempts), f"{LABELS[method]}: {q.phrase}")
            a = run.of(method)
            say(f"  {LABELS[method]}: SR {sum(x.success for x in a)}/{len(a)}")
        if cfg.png:
            run.png = str(folder / "map.png")
            sr = ", ".join(f"{LABELS[m]} {100 * _rate(run.of(m)):.0f}%" for m in answerers)
            layers.title = f"{env.name}: {run.explored_m2:.0f} m^2 explored, {run.memories} memories; SR {sr}"
            draw_map(grid, layers, run.png)
        mem.close()
        run.seconds = time.perf_counter() - t0
        return run
    finally:
        env.close()


def _fixed_kinds(name: str, objects: list[SceneObject], seen: set[int]) -> list[str] | None:
    """The gallery's questions: every kind it holds, in its fixed order, those the robot saw
    (None elsewhere: `make_queries` picks them)."""
    if name != GALLERY:
        return None
    from .sim.gallery import PHOTOS

    saw = {o.kind for o in objects if o.id in seen}
    return [k for k in PHOTOS if k in saw]


def _reachable(env: Any, objects: list[SceneObject], radius: float) -> set[int]:
    """Objects a robot could get within `radius` (less a margin) of: within that of the floor
    reachable from the start (simulator ground truth, when the backend has its walls). Asking
    to drive to a thing on a ledge nobody can reach tests nothing of the memory."""
    segs = getattr(env, "wall_segments", None)
    if segs is None:
        return {o.id for o in objects}
    obs = env.reset()
    truth = reachable_floor(segs(), (obs.pose.x, obs.pose.y), 0.25)
    return {o.id for o in objects if truth.distance(o.x, o.y) <= max(0.5, radius - 1.0)}


def _rate(a: list[Attempt]) -> float:
    return sum(x.success for x in a) / len(a) if a else 0.0


def _answerers(
    cfg: DemoConfig,
    env: Any,
    grid: Any,
    mem: Any,
    rep: Any,
    objects: list[SceneObject],
    kind_of: dict[int, str],
    queries: list[DemoQuery],
    folder: Path,
    say: Callable[[str], None],
) -> dict[str, Callable[[DemoQuery], Answer]]:
    """question -> (found, position, note) for each method the config names."""
    from .agent.methods import create_method

    out: dict[str, Callable[[DemoQuery], Answer]] = {}

    def via(method: Any) -> Callable[[DemoQuery], Answer]:
        def ask(q: DemoQuery) -> Answer:
            a = method.ask(q.question)
            if not (a.found and a.position):
                return (False, None, _declined(a.notes))
            return (True, (float(a.position[0]), float(a.position[1])), "")

        return ask

    for m in cfg.methods:
        if m == "image":
            out[m] = _image_answerer(env, grid, mem, rep, objects, queries, folder, say, cfg.pictures)
        elif m == "oracle":
            out[m] = _oracle_answerer(cfg, mem, rep, kind_of, folder)
        elif m == "text":
            out[m] = via(create_method(cfg.text_method, mem))
        else:
            out[m] = via(create_method("random", mem, seed=cfg.seed))
    return out


def _oracle_answerer(
    cfg: DemoConfig, mem: Any, rep: Any, kind_of: dict[int, str], folder: Path
) -> Callable[[DemoQuery], Answer]:
    """The agent over a memory whose perception is the simulator's labels; the object is then
    placed where its label box and the depth image put it in the answering keyframe (what a
    detector with a depth camera gives), not at the keyframe's pose."""
    from .agent.methods import create_method

    labels: dict[int, dict[int, tuple[int, float, float]]] = rep.keyframe_labels
    px = {mid: {o: lab[0] for o, lab in labels.get(mid, {}).items()} for mid in rep.keyframes}
    omem = oracle_memory(folder / "oracle.mem", mem, px, kind_of)
    by_time = {r.t: r.id for r in mem.all_records()}  # oracle memory -> robot memory ids
    method = create_method(cfg.oracle_method, omem)

    def ask(q: DemoQuery) -> Answer:
        a = method.ask(q.question)
        if not a.found or not a.position or not a.evidence:
            return (False, None, "not found")
        mid = by_time.get(a.evidence[0].t)
        seen = [lab for o, lab in labels.get(mid, {}).items() if kind_of.get(o) == q.kind] if mid else []
        if not seen:
            return (True, (float(a.position[0]), float(a.position[1])), "at the memory's pose")
        _, x, y = max(seen)
        return (True, (x, y), "")

    return ask


def _image_answerer(
    env: Any,
    grid: Any,
    mem: Any,
    rep: Any,
    objects: list[SceneObject],
    queries: list[DemoQuery],
    folder: Path,
    say: Callable[[str], None],
    source: str = "view",
) -> Callable[[DemoQuery], Answer]:
    """A picture per query (a view of the instance the robot saw most often, or the object's
    sprite from the WAD) answered with the image tool's top hit."""
    keyframes = np.asarray([(r.pose.x, r.pose.y) for r in mem.all_records()]).reshape(-1, 2)
    counts: dict[int, int] = {}
    for vis in rep.keyframes.values():
        for i in vis:
            counts[i] = counts.get(i, 0) + 1
    pictures: dict[str, np.ndarray] = {}
    (folder / "queries").mkdir(exist_ok=True)
    eta = Eta(say, "  image queries, pictures rendered", len(queries))
    for n, q in enumerate(queries):
        eta.update(n, q.phrase)
        inst = [o for o in objects if o.kind == q.kind and o.id in counts]
        if not inst:
            continue
        obj = max(inst, key=lambda o: (counts[o.id], -o.id))
        if source == "sprite":
            pic = _sprite(env, q.kind)
        else:
            env.reset()  # a new episode: items the robot picked up while exploring are back
            pic = query_picture(env, grid, obj, keyframes, env.robot.radius)
        if pic is not None:
            pictures[q.kind] = pic
            Image.fromarray(pic).save(folder / "queries" / f"{q.kind}.png")
    eta.update(len(queries), f"{len(pictures)} of {len(queries)} objects pictured")
    tool = TOOLS["search_image"]
    call = tool.validate({})

    def ask(q: DemoQuery) -> Answer:
        pic = pictures.get(q.kind)
        if pic is None:
            return (False, None, "no picture")
        hits = tool.run(mem, call, 1, image=pic)
        if not hits:
            return (False, None, "not found")
        p = hits[0].memory.pose
        return (True, (p.x, p.y), "")

    return ask


def _sprite(env: Any, kind: str) -> np.ndarray | None:
    """The object's sprite from the environment's WAD (None where there is none)."""
    from .sim.sprites import has_sprite, sprite_image

    wad = getattr(env, "wad_path", None)
    if wad is None or not has_sprite(kind, wad):
        return None
    return sprite_image(kind, wad)


def _attempt(
    cfg: DemoConfig, env: Any, grid: Any, method: str, q: DemoQuery, ans: Answer, layers: MapLayers
) -> Attempt:
    found, pos, note = ans
    if not found or pos is None:
        return Attempt(method, q.kind, q.phrase, False, None, math.inf, math.inf, False, math.inf, 0.0, note)
    obs = env.reset()  # every query starts from the map's start
    nav = navigate_to(env, copy.deepcopy(grid), pos, cfg.drive_steps, start=obs)
    final = q.nearest(nav.last.pose.x, nav.last.pose.y)
    ok = final <= cfg.success_radius
    path = nav.plan.length_m if nav.plan is not None and nav.plan.ok else math.inf
    layers.answers.append((LABELS[method], pos[0], pos[1], ok))
    layers.drives.append(nav.trajectory)
    return Attempt(
        method, q.kind, q.phrase, True, pos, q.nearest(*pos), final, ok, path, nav.driven_m, nav.reason
    )
