"""`ravenmem demo`: a simulated robot explores a Freedoom map while building its memory
(Phase I), then answers object queries from that memory and drives to each answer with A*
on the map it built, without exploring again (Phase II). Offline, on CPU.

    from ravenmem.demo import DemoConfig, run_demo
    report = run_demo(DemoConfig(out="demo.mem"))
    print(report.table())
"""

from __future__ import annotations

import json
import math
import shutil
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from .errors import InputError
from .fsio import atomic_write_json
from .nav.render import MapLayers, draw_map
from .robot.explore import ExploreConfig, ExploreReport
from .robot.mission import explore_into, navigate_to
from .sim.base import create_env
from .sim.queries import DemoQuery, make_queries

DEFAULT_ENV = "vizdoom:freedoom2/MAP02"


@dataclass
class DemoConfig:
    """Demo settings. `method`: 'offline' (the offline reasoner), 'embedder-only' (top-1 text
    search) or 'auto' (offline when the agent package is there). A query succeeds when the
    robot ends within `success_radius` metres of the nearest true instance."""

    env: str = DEFAULT_ENV
    out: str = "demo.mem"
    png: str | None = "demo_map.png"
    steps: int = 3000
    method: str = "auto"
    embedder: Any = "offline"  # a spec, or an Embedder instance
    queries: int = 8
    success_radius: float = 3.0
    drive_steps: int = 800
    keyframe_dist: float = 2.0
    keyframe_turn: float = math.radians(45.0)
    overwrite: bool = False
    start_time: float | None = None


@dataclass
class QueryResult:
    query: str
    kind: str
    found: bool
    answer: tuple[float, float] | None
    answer_dist: float  # metres from the answer to the nearest true instance (inf if none)
    final_dist: float  # metres from where the robot stopped to the nearest true instance
    success: bool
    path_m: float  # planned A* path length (inf when no plan)
    driven_m: float
    note: str = ""


@dataclass
class DemoReport:
    env: str
    method: str
    memory: str
    png: str | None
    memories: int
    explore: ExploreReport
    coverage: float | None
    results: list[QueryResult] = field(default_factory=list)
    baselines: dict[str, float] = field(default_factory=dict)  # SR of the answer position, by method
    wall_seconds: float = 0.0
    success_radius: float = 3.0

    @property
    def sr(self) -> float:
        return sum(r.success for r in self.results) / len(self.results) if self.results else 0.0

    def table(self) -> str:
        """The per-query table and the summary lines the CLI prints."""

        def m(v: float) -> str:
            return f"{v:.1f}" if math.isfinite(v) else "-"

        rows = [
            f"{'query':<40} {'answer (x, y) m':>17} {'answer->true m':>14} {'robot->true m':>13} "
            f"{'success':>7} {'path m':>7}"
        ]
        for r in self.results:
            ans = f"({r.answer[0]:.1f}, {r.answer[1]:.1f})" if r.answer else "not found"
            rows.append(
                f"{r.query[:40]:<40} {ans:>17} {m(r.answer_dist):>14} {m(r.final_dist):>13} "
                f"{('yes' if r.success else 'no'):>7} {m(r.path_m):>7}"
            )
        cov = f"{100 * self.coverage:.0f}% of the reachable floor, " if self.coverage is not None else ""
        rows.append("")
        rows.append(
            f"explored: {cov}{self.explore.coverage[-1][2] if self.explore.coverage else 0:.0f} m^2 in "
            f"{self.explore.steps} steps ({self.explore.stop_reason}); memories kept: {self.memories}"
        )
        rows.append(
            f"SR ({self.method}, robot within {self.success_radius:g} m after driving): "
            f"{sum(r.success for r in self.results)}/{len(self.results)} = {100 * self.sr:.0f}%"
        )
        if self.baselines:
            rows.append(
                "SR of the answer position: "
                + ", ".join(f"{k} {100 * v:.0f}%" for k, v in self.baselines.items())
            )
        rows.append(
            f"wall time: {self.wall_seconds:.0f} s; memory: {self.memory}"
            + (f"; map: {self.png}" if self.png else "")
        )
        return "\n".join(rows)

    def as_dict(self) -> dict[str, Any]:
        d = {k: v for k, v in asdict(self).items() if k != "explore"}
        d["sr"] = self.sr
        d["explore"] = {
            k: v for k, v in self.explore.as_dict().items() if k not in ("trajectory", "keyframes")
        }
        return json.loads(
            json.dumps(d, default=lambda o: None if isinstance(o, float) and not math.isfinite(o) else o)
        )


def _answerer(name: str, mem: Any) -> tuple[str, Callable[[str], tuple[bool, tuple[float, float] | None]]]:
    """A function question -> (found, position) for the chosen method, and the method's name."""
    if name in ("auto", "offline", "random", "raven"):
        try:
            from .agent.methods import create_method

            method = create_method("offline" if name == "auto" else name, mem)
        except ImportError:
            if name != "auto":
                raise
        else:

            def ask(q: str) -> tuple[bool, tuple[float, float] | None]:
                a = method.ask(q)
                pos = (float(a.position[0]), float(a.position[1])) if a.position else None
                return bool(a.found and pos is not None), pos

            return method.name, ask
    if name not in ("auto", "embedder-only"):
        raise InputError(f"demo: unknown method {name!r}; choose auto, offline, embedder-only or random")

    def top1(q: str) -> tuple[bool, tuple[float, float] | None]:
        hits = mem.search_text(q, k=1)
        return (True, (hits[0].memory.pose.x, hits[0].memory.pose.y)) if hits else (False, None)

    return "embedder-only", top1


def _baselines(mem: Any, queries: list[DemoQuery], radius: float, main: dict[str, float]) -> dict[str, float]:
    """SR of the answer position alone: the chosen method, top-1 text search, and a random
    memory (its exact expectation: the share of memories within `radius` of an instance)."""
    out = dict(main)
    if queries and "embedder-only" not in out:
        top = [mem.search_text(q.question, k=1) for q in queries]
        out["embedder-only top-1"] = sum(
            bool(h) and q.nearest(h[0].memory.pose.x, h[0].memory.pose.y) <= radius
            for q, h in zip(queries, top)
        ) / len(queries)
    if queries:
        recs = mem.all_records()
        if recs:
            out["random memory (expected)"] = sum(
                sum(q.nearest(r.pose.x, r.pose.y) <= radius for r in recs) / len(recs) for q in queries
            ) / len(queries)
    return out


def run_demo(cfg: DemoConfig | None = None, progress: Callable[[str], None] | None = None) -> DemoReport:
    """Run both phases and write the memory folder, `demo.json` in it and the map PNG."""
    import ravenmem

    cfg = cfg or DemoConfig()
    say = progress or (lambda _m: None)
    t0 = time.perf_counter()
    out = Path(cfg.out)
    if out.exists():
        if not cfg.overwrite:
            raise InputError(f"{out} already exists; pass --overwrite or choose another --out")
        if not (out / "memory.json").exists() and any(out.iterdir()):
            raise InputError(f"{out} is not a ravenmem memory folder; refusing to delete it")
        shutil.rmtree(out)
    env = create_env(cfg.env, start_time=cfg.start_time)
    try:
        mem = ravenmem.create(out, embedder=cfg.embedder, ocr=False)
        say(f"phase I: exploring {env.name} for up to {cfg.steps} steps")
        ecfg = ExploreConfig(
            steps=cfg.steps, keyframe_dist=cfg.keyframe_dist, keyframe_turn=cfg.keyframe_turn
        )
        grid, rep = explore_into(env, mem, ecfg, progress=say)
        cov = rep.coverage[-1][3] if rep.coverage else None
        seen = {i for vis in rep.keyframes.values() for i in vis}
        queries = make_queries(env.objects(), seen, cfg.queries)
        method_name, ask = _answerer(cfg.method, mem)
        say(f"phase II: {len(queries)} queries answered by {method_name}, driven with A*")
        results: list[QueryResult] = []
        layers = MapLayers(
            trajectory=list(rep.trajectory),
            start=rep.trajectory[0] if rep.trajectory else None,
            memories=[(r.pose.x, r.pose.y) for r in mem.all_records()],
        )
        obs = env.observe()
        answer_hits = 0
        for i, q in enumerate(queries, start=1):
            found, pos = ask(q.question)
            note, path_m, driven = "", math.inf, 0.0
            if found and pos is not None:
                nav = navigate_to(env, grid, pos, cfg.drive_steps, start=obs)
                obs = nav.last
                driven = nav.driven_m
                if nav.plan is not None and nav.plan.ok:
                    path_m = nav.plan.length_m
                layers.paths += nav.paths
                layers.drives.append(nav.trajectory)
                note = nav.reason
                answer_hits += q.nearest(*pos) <= cfg.success_radius
            else:
                note = "not found in memory"
            final = q.nearest(obs.pose.x, obs.pose.y) if found else math.inf
            ok = found and final <= cfg.success_radius
            results.append(
                QueryResult(
                    q.question,
                    q.kind,
                    found,
                    pos if found else None,
                    q.nearest(*pos) if found and pos else math.inf,
                    final,
                    ok,
                    path_m,
                    driven,
                    note,
                )
            )
            layers.truths += [(q.kind, x, y) for x, y in q.instances]
            if found and pos is not None:
                layers.answers.append((f"Q{i}", pos[0], pos[1], ok))
            say(f"  Q{i} {q.phrase}: {'found' if found else 'not found'}, success={ok}")
        main = {method_name: answer_hits / len(queries)} if queries else {}
        report = DemoReport(
            env=env.name,
            method=method_name,
            memory=str(out),
            png=cfg.png,
            memories=mem.count(),
            explore=rep,
            coverage=cov,
            results=results,
            baselines=_baselines(mem, queries, cfg.success_radius, main),
            success_radius=cfg.success_radius,
        )
        if cfg.png:
            layers.title = (
                f"{env.name}: explored {rep.coverage[-1][2] if rep.coverage else 0:.0f} m^2, "
                f"{report.memories} memories, SR {100 * report.sr:.0f}% ({method_name})"
            )
            draw_map(grid, layers, cfg.png)
        report.wall_seconds = time.perf_counter() - t0
        atomic_write_json(out / "demo.json", report.as_dict(), indent=1)
        mem.close()
        return report
    finally:
        env.close()
