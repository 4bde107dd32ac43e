"""`ravenmem explore`, `ravenmem navigate` and `ravenmem demo`: the simulated robot's commands."""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path
from typing import Annotated, Any

import typer

MemoryOpt = Annotated[Path, typer.Option("--memory", "-m", help="memory folder")]
JsonOpt = Annotated[bool, typer.Option("--json", help="machine-readable output")]
EnvOpt = Annotated[
    str, typer.Option("--env", help="environment, e.g. vizdoom:freedoom2/MAP01 or synthetic:rooms")
]


def _say(msg: str) -> None:
    sys.stderr.write(msg + "\n")


def explore(
    memory: MemoryOpt,
    env: EnvOpt = "vizdoom:freedoom2/MAP02",
    steps: Annotated[int, typer.Option(help="control steps (one step = 2 Doom tics)")] = 3000,
    embedder: Annotated[str, typer.Option(help="embedder spec for the new memory")] = "offline",
    png: Annotated[Path | None, typer.Option(help="also draw the map here")] = None,
    keyframe_dist: Annotated[float, typer.Option(help="metres moved between keyframes")] = 2.0,
    keyframe_turn: Annotated[float, typer.Option(help="degrees turned between keyframes")] = 45.0,
    json_out: JsonOpt = False,
) -> None:
    """Phase I: explore with frontiers, build the occupancy map and the memory."""
    import ravenmem
    from ravenmem.errors import InputError
    from ravenmem.nav.render import MapLayers, draw_map
    from ravenmem.robot.explore import ExploreConfig
    from ravenmem.robot.mission import explore_into
    from ravenmem.sim.base import create_env

    if steps < 1:
        raise InputError(f"--steps must be >= 1, got {steps}")
    sim = create_env(env)
    try:
        mem = ravenmem.create(memory, embedder=embedder, ocr=False)
        cfg = ExploreConfig(
            steps=steps, keyframe_dist=keyframe_dist, keyframe_turn=math.radians(keyframe_turn)
        )
        grid, rep = explore_into(sim, mem, cfg, progress=_say)
        if png is not None:
            draw_map(
                grid,
                MapLayers(
                    trajectory=rep.trajectory,
                    memories=[(r.pose.x, r.pose.y) for r in mem.all_records()],
                    start=rep.trajectory[0] if rep.trajectory else None,
                    title=sim.name,
                ),
                png,
            )
        cov = rep.coverage[-1] if rep.coverage else (0, 0.0, 0.0, None)
        out: dict[str, Any] = {
            "env": sim.name,
            "memory": str(memory),
            "steps": rep.steps,
            "stop_reason": rep.stop_reason,
            "explored_m2": cov[2],
            "coverage": cov[3],
            "memories": mem.count(),
            "distance_m": rep.distance_m,
            "wall_s": rep.wall_seconds,
            "png": str(png) if png else None,
        }
        mem.close()
    finally:
        sim.close()
    if json_out:
        sys.stdout.write(json.dumps(out, indent=2) + "\n")
        return
    frac = f" ({100 * out['coverage']:.0f}% of the reachable floor)" if out["coverage"] is not None else ""
    sys.stdout.write(
        f"explored {out['explored_m2']:.0f} m^2{frac} in {out['steps']} steps, {out['stop_reason']}; "
        f"{out['memories']} memories in {memory}; {out['wall_s']:.0f} s\n"
    )


def navigate(
    memory: MemoryOpt,
    to: Annotated[str | None, typer.Option("--to", help="what to go to, e.g. 'explosive barrel'")] = None,
    x: Annotated[float | None, typer.Option(help="or a goal position x (m)")] = None,
    y: Annotated[float | None, typer.Option(help="goal position y (m)")] = None,
    method: Annotated[str, typer.Option(help="auto | offline | embedder-only | random")] = "auto",
    max_steps: Annotated[int, typer.Option(help="driving budget in control steps")] = 1500,
    png: Annotated[Path | None, typer.Option(help="draw the map with the path here")] = None,
    json_out: JsonOpt = False,
) -> None:
    """Phase II: answer from memory, plan with A* on the saved map, and drive there."""
    import ravenmem
    from ravenmem.demo import _answerer
    from ravenmem.errors import InputError
    from ravenmem.nav.grid import OccupancyGrid
    from ravenmem.nav.render import MapLayers, draw_map
    from ravenmem.robot.mission import load_exploration, navigate_to
    from ravenmem.sim.base import create_env
    from ravenmem.sim.queries import match_kind

    if (to is None) == (x is None or y is None):
        raise InputError("give either --to TEXT or both --x and --y")
    meta = load_exploration(memory)
    grid = OccupancyGrid.load(memory)
    mem = ravenmem.open(memory)
    sim = create_env(meta["env"])
    try:
        found, used = True, "position"
        goal: tuple[float, float] | None = (float(x), float(y)) if x is not None and y is not None else None
        if to is not None:
            used, ask = _answerer(method, mem)
            question = to if to.rstrip().endswith("?") else f"Where did you see the {to}?"
            found, goal = ask(question)
        out: dict[str, Any] = {"query": to, "method": used, "found": found, "answer": goal}
        obs = sim.reset()
        if found and goal is not None:
            nav = navigate_to(sim, grid, goal, max_steps, start=obs)
            obs = nav.last
            plan = nav.plan
            out.update(
                planned=bool(plan and plan.ok),
                reason=nav.reason,
                reached=nav.reached,
                path_m=plan.length_m if plan and plan.ok else None,
                driven_m=nav.driven_m,
                snapped_goal=plan.goal if plan and plan.ok and plan.snapped else None,
            )
            if png is not None:
                draw_map(
                    grid,
                    MapLayers(
                        trajectory=nav.trajectory,
                        paths=nav.paths,
                        start=nav.trajectory[0],
                        answers=[(to or "goal", goal[0], goal[1], nav.reached)],
                        title=sim.name,
                    ),
                    png,
                )
        out["final"] = (obs.pose.x, obs.pose.y)
        kind = match_kind(to, [o.kind for o in sim.objects()]) if to else None
        if kind is not None:
            inst = [(o.x, o.y) for o in sim.objects() if o.kind == kind]
            out["true_kind"] = kind
            out["final_to_true_m"] = min(math.dist(out["final"], p) for p in inst)
        mem.close()
    finally:
        sim.close()
    if json_out:
        sys.stdout.write(json.dumps(out, indent=2, default=str) + "\n")
        return
    if not out["found"]:
        sys.stdout.write(f"{to!r}: not found in memory ({out['method']}); the robot stays put\n")
        return
    gx, gy = out["answer"]
    line = f"answer ({out['method']}): ({gx:.2f}, {gy:.2f})"
    if out.get("planned"):
        line += f"; A* path {out['path_m']:.1f} m; drove {out['driven_m']:.1f} m, {out['reason']}"
    else:
        line += f"; no path: {out.get('reason')}"
    line += f"; robot at ({out['final'][0]:.2f}, {out['final'][1]:.2f})"
    if "final_to_true_m" in out:
        line += f"; {out['final_to_true_m']:.1f} m from the nearest true {out['true_kind']}"
    sys.stdout.write(line + "\n")


def demo(
    out: Annotated[Path, typer.Option("--out", help="memory folder to write")] = Path("demo.mem"),
    env: EnvOpt = "vizdoom:freedoom2/MAP02",
    steps: Annotated[int, typer.Option(help="exploration budget in control steps")] = 3000,
    queries: Annotated[int, typer.Option(help="object queries in Phase II")] = 8,
    method: Annotated[str, typer.Option(help="auto | offline | embedder-only | random")] = "auto",
    png: Annotated[Path, typer.Option(help="map picture")] = Path("demo_map.png"),
    success_radius: Annotated[float, typer.Option(help="metres from the nearest true instance")] = 3.0,
    overwrite: Annotated[bool, typer.Option(help="replace an existing --out memory")] = False,
    json_out: JsonOpt = False,
) -> None:
    """Explore a Freedoom map into a memory, then answer queries and drive there (offline, CPU)."""
    from ravenmem.demo import DemoConfig, run_demo

    cfg = DemoConfig(
        env=env,
        out=str(out),
        png=str(png),
        steps=steps,
        queries=queries,
        method=method,
        success_radius=success_radius,
        overwrite=overwrite,
    )
    report = run_demo(cfg, progress=_say)
    if json_out:
        sys.stdout.write(json.dumps(report.as_dict(), indent=2) + "\n")
    else:
        sys.stdout.write(report.table() + "\n")


def register(app: typer.Typer) -> None:
    """Add `explore`, `navigate` and `demo` to the main `ravenmem` command."""
    app.command("explore")(explore)
    app.command("navigate")(navigate)
    app.command("demo")(demo)
