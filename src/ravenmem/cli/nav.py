"""`ravenmem map`, `navigate`, `explore` and `demo`: maps, planning and the simulated robot."""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path
from typing import Annotated, Any

import typer

from ._console import rounded
from .options import (
    ANGLE,
    CELL_SIZE,
    COUNT,
    DISTANCE,
    GOAL,
    OUTPUT,
    PICTURE,
    POINT,
    ROBOT_RADIUS,
    STEPS,
    Force,
)

MemoryOpt = Annotated[Path, typer.Option("--memory", "-m", help="memory folder")]
JsonOpt = Annotated[bool, typer.Option("--json", help="machine-readable output")]
EnvOpt = Annotated[
    str, typer.Option("--env", help="environment, e.g. vizdoom:freedoom2/MAP01 or synthetic:rooms")
]


def _say(msg: str) -> None:
    sys.stderr.write(msg + "\n")


def parse_start(from_: str | None) -> tuple[float, float] | None:
    """`--from x,y` (map metres) of navigate and ask --navigate; None when not given."""
    if from_ is None:
        return None
    start = _xy(from_, "--from")
    if start is None:
        from ravenmem.errors import InputError

        raise InputError(f"--from: expected 'x,y' in metres, got {from_!r}")
    return start


def _xy(text: str, what: str) -> tuple[float, float] | None:
    """'x,y' -> (x, y); None when the text is not two numbers."""
    parts = [p for p in text.replace(" ", "").split(",") if p]
    if len(parts) != 2:
        return None
    try:
        x, y = float(parts[0]), float(parts[1])
    except ValueError:
        return None
    if not (math.isfinite(x) and math.isfinite(y)):
        from ravenmem.errors import InputError

        raise InputError(f"{what}: not finite: {text!r}")
    return (x, y)


def _layers(grid: Any, mem: Any, title: str) -> Any:
    """Trajectory, memories (on the map) and start, for a map picture."""
    from ravenmem.nav.goals import to_map_xy
    from ravenmem.nav.render import MapLayers

    traj = [(float(x), float(y)) for x, y in grid.trajectory]
    memories = [to_map_xy(grid, r.pose.xyz) for r in mem.all_records()] if mem is not None else []
    return MapLayers(trajectory=traj, memories=memories, start=traj[0] if traj else None, title=title)


def map_cmd(
    memory: MemoryOpt,
    out: Annotated[Path | None, PICTURE, typer.Option("--out", help="draw the map here (PNG)")] = None,
    from_: Annotated[
        list[Path] | None,
        typer.Option("--from", help="recording(s) of this memory to build the map from (repeatable)"),
    ] = None,
    refresh: Annotated[
        bool, typer.Option(help="re-read the memory's recordings and add depth frames not in the map yet")
    ] = False,
    rebuild: Annotated[bool, typer.Option(help="build the map again from the recordings")] = False,
    intrinsics: Annotated[
        str | None, typer.Option(help="depth camera when building: fr1 | fr2 | fr3 | kinect | fx,fy,cx,cy")
    ] = None,
    resolution: Annotated[float | None, CELL_SIZE, typer.Option(help="cell size (m) when building")] = None,
    robot_radius: Annotated[
        float | None, ROBOT_RADIUS, typer.Option(help="robot radius (m) when building")
    ] = None,
    nav2: Annotated[
        Path | None,
        OUTPUT,
        typer.Option("--nav2", help="also export a Nav2 map_server map: NAME.yaml (+ NAME.pgm)"),
    ] = None,
    import_nav2: Annotated[
        Path | None, typer.Option("--import-nav2", help="store this map_server YAML as the memory's map")
    ] = None,
    overwrite: Annotated[bool, typer.Option(help="with --import-nav2: replace an existing map")] = False,
    force: Force = False,
    json_out: JsonOpt = False,
) -> None:
    """Build (if missing) or refresh the memory's occupancy map, draw it, export it for Nav2."""
    import ravenmem
    from ravenmem.errors import InputError
    from ravenmem.memory.folder import MAP_GRID
    from ravenmem.nav.grid import OccupancyGrid
    from ravenmem.nav.mapping import map_counts, recording_config
    from ravenmem.nav.render import draw_map
    from ravenmem.robot.maps import build_map
    from ravenmem.ros.nav2 import export_map_server, import_map_server

    if (resolution is not None or robot_radius is not None) and not rebuild:
        raise InputError("--resolution and --robot-radius change how a map is built: add --rebuild")
    out_json: dict[str, Any] = {"memory": str(memory)}
    with ravenmem.open(memory) as mem:
        if import_nav2 is not None:
            if (memory / MAP_GRID).exists() and not overwrite:
                raise InputError(f"{memory} already has a map; pass --overwrite to replace it")
            grid = import_map_server(import_nav2)
            grid.save(memory)
        elif rebuild or refresh or from_ or not (memory / MAP_GRID).exists():
            cfg = None
            if rebuild:
                base = recording_config()
                cfg = recording_config(
                    resolution if resolution is not None else base.resolution,
                    robot_radius if robot_radius is not None else base.robot_radius,
                )
            grid, rep = build_map(mem, intrinsics, cfg, rebuild=rebuild, recordings=from_ or (), say=_say)
            out_json["built"] = rep
        else:
            grid = OccupancyGrid.load(memory)
        if out is not None:
            draw_map(grid, _layers(grid, mem, f"{memory.name}: {grid.kind} map"), out)
            out_json["png"] = str(out)
    if nav2 is not None:
        yml, pgm = export_map_server(grid, nav2)
        out_json["nav2"] = {"yaml": str(yml), "image": str(pgm)}
    out_json |= map_counts(grid) | {
        "kind": grid.kind,
        "origin": list(grid.origin),
        "shape": list(grid.shape),
        "robot_radius_m": grid.config.robot_radius,
        "frame": grid.frame.as_dict(),
    }
    if json_out:
        sys.stdout.write(json.dumps(out_json, indent=2) + "\n")
        return
    m2 = grid.resolution**2
    sys.stdout.write(
        f"{grid.kind} map of {memory}: {out_json['free']} free ({out_json['free'] * m2:.1f} m^2), "
        f"{out_json['occupied']} occupied, {out_json['unknown']} unknown cells of {grid.resolution:g} m; "
        f"floor: {grid.frame.method}"
        + (f"; picture: {out}" if out else "")
        + (f"; Nav2 map: {nav2}" if nav2 else "")
        + "\n"
    )


def navigate(
    memory: MemoryOpt,
    to: Annotated[
        str, GOAL, typer.Option("--to", help="goal 'x,y' (map metres) or what to go to ('the red box')")
    ],
    from_: Annotated[
        str | None,
        POINT,
        typer.Option(
            "--from",
            help="start 'x,y' (default: the robot's last pose, or the nearest cell that reaches the goal)",
        ),
    ] = None,
    method: Annotated[
        str, typer.Option(help="how a text goal is answered: offline | embedder-only | ...")
    ] = "offline",
    robot_radius: Annotated[
        float | None, ROBOT_RADIUS, typer.Option(help="robot radius (m); default: the map's")
    ] = None,
    drive: Annotated[
        bool, typer.Option(help="simulated memories: also drive there in the simulator, from its start")
    ] = False,
    max_steps: Annotated[
        int, STEPS, typer.Option(help="with --drive: driving budget in control steps")
    ] = 1500,
    png: Annotated[Path | None, PICTURE, typer.Option(help="draw the map with the path here")] = None,
    force: Force = False,
    json_out: JsonOpt = False,
) -> None:
    """Plan with A* on the memory's own map to a position or to an answer (`nav.goals.goal_for`,
    as `ask --navigate` and the robot links do); print the path and the goal as a ROS
    PoseStamped in the memory's frame. Unknown or blocked goals snap to the nearest reachable
    cell that sees them. Exit 1 when there is no path, saying whether the start or the goal is
    the problem; with --json the plan is printed in every case (an input error too, exit 2)."""
    from ravenmem.errors import RavenmemError
    from ravenmem.nav.render import draw_map

    out: dict[str, Any] = {"memory": str(memory), "to": to}
    try:
        gp, grid, start = _plan(memory, to, from_, method, robot_radius, drive, out)
    except RavenmemError as e:
        if json_out:
            sys.stdout.write(
                json.dumps(out | {"ok": False, "problem": "input", "reason": str(e)}, indent=2) + "\n"
            )
        raise
    out |= gp.as_dict()
    if gp.ok and drive:
        assert gp.goal is not None
        out["drive"] = _drive(memory, grid, (gp.goal[0], gp.goal[1]), max_steps)
    if png is not None:
        layers = _layers(grid, None, f"{memory.name}: A* to {to}")
        layers.paths = [gp.plan.waypoints] if gp.ok else []
        layers.start = start
        layers.goals = [gp.goal] if gp.goal else []
        if "drive" in out:
            layers.drives = [out["drive"].pop("trajectory")]
        draw_map(grid, layers, png)
        out["png"] = str(png)
    if json_out:
        sys.stdout.write(json.dumps(out, indent=2, default=str) + "\n")
    if not gp.ok:
        if not json_out:
            sys.stderr.write(f"no path (the {gp.problem} is the problem): {gp.reason}\n")
        raise typer.Exit(1)
    if json_out:
        return
    g = gp.goal or (0.0, 0.0, 0.0)
    line = (
        f"A* path {gp.plan.length_m:.2f} m, {len(gp.plan.waypoints)} waypoints, from "
        f"({start[0]:.2f}, {start[1]:.2f}) to ({g[0]:.2f}, {g[1]:.2f}) facing {math.degrees(g[2]):.0f} deg"
        if start
        else ""
    )
    if gp.heading is not None:
        line += f" ({gp.heading.reason})"
    if gp.plan.snapped:
        line += (
            f" (goal snapped from ({gp.target[0]:.2f}, {gp.target[1]:.2f}))" if gp.target else " (snapped)"
        )
    if "answer" in out:
        where = ", ".join(f"{v:.2f}" for v in out["answer"]["position"] or [])
        line = f"answer ({out['answer']['method']}): ({where}); " + line
    if "drive" in out:
        d = out["drive"]
        line += f"; drove {d['driven_m']:.1f} m: {d['reason']}, robot at ({d['final'][0]:.2f}, {d['final'][1]:.2f})"
    sys.stdout.write(line + "\n")
    for note in gp.notes:
        sys.stdout.write(f"  note: {note}\n")
    sys.stdout.write(json.dumps(rounded(gp.pose_stamped())) + "\n")


def _declined(to: str, answer: Any) -> str:
    """One line for a goal the method would not place: its reason, the closest misses (a search
    lists the same memories) and how to go to one of them anyway."""
    line = f"{to!r}: not found in memory ({answer.method})"
    if answer.text:
        line += f": {answer.text.rstrip('.')}"
    misses = answer.evidence[:3]
    if misses:
        line += "; closest misses: " + ", ".join(
            f"m{e.id} (score {e.score:.2f}) at ({e.x:.2f}, {e.y:.2f})"
            if e.score is not None
            else f"m{e.id} at ({e.x:.2f}, {e.y:.2f})"
            for e in misses
        )
        line += (
            f"; to go to one anyway: --to {misses[0].x:.2f},{misses[0].y:.2f}, or --method embedder-only "
            "(the top hit, no threshold)"
        )
    return line + "; the robot stays put"


def _plan(
    memory: Path,
    to: str,
    from_: str | None,
    method: str,
    robot_radius: float | None,
    drive: bool,
    out: dict[str, Any],
) -> tuple[Any, Any, tuple[float, float] | None]:
    """(the goal plan, the map, the start) of `navigate`; the answer goes into `out`."""
    import ravenmem
    from ravenmem.agent.methods import create_method
    from ravenmem.errors import InputError
    from ravenmem.nav.goals import PositionGoal, goal_for, last_pose
    from ravenmem.nav.grid import OccupancyGrid

    grid = OccupancyGrid.load(memory)
    start = parse_start(from_)
    if drive and from_ is not None:
        raise InputError("--drive starts where the simulator starts; leave out --from")
    goal_xy = _xy(to, "--to")
    with ravenmem.open(memory) as mem:
        if drive and len(grid.trajectory):
            start = (float(grid.trajectory[0][0]), float(grid.trajectory[0][1]))  # the simulator's start
        # no --from: goal_for starts at the robot's last pose, or near it when that is cut off
        if goal_xy is not None:
            target: Any = PositionGoal(position=list(goal_xy))
        else:
            question = to if to.rstrip().endswith("?") else f"Where did you see the {to}?"
            name = "offline" if method == "auto" else method
            target = create_method(name, mem).ask(question)
            target.frame_id, target.map_id = mem.frame_id, mem.map_id
            out["answer"] = {
                "method": target.method,
                "found": target.found,
                "position": target.position,
                "text": target.text,
            }
        gp = goal_for(target, mem, start, robot_radius=robot_radius, grid=grid)
        if goal_xy is None and not target.found and not gp.ok:
            gp.plan.reason = _declined(to, target)  # why, and what a search finds instead
        return gp, grid, gp.start or start or last_pose(grid, mem)


def _drive(memory: Path, grid: Any, goal: Any, max_steps: int) -> dict[str, Any]:
    """Drive to `goal` in the simulator the memory was explored in (from its start)."""
    from ravenmem.errors import InputError
    from ravenmem.robot.mission import load_exploration, navigate_to
    from ravenmem.sim.base import create_env

    if goal is None:
        raise InputError("no goal to drive to")
    meta = load_exploration(memory)
    sim = create_env(meta["env"])
    try:
        obs = sim.reset()
        nav = navigate_to(sim, grid, (float(goal[0]), float(goal[1])), max_steps, start=obs)
        return {
            "env": sim.name,
            "reached": nav.reached,
            "reason": nav.reason,
            "driven_m": nav.driven_m,
            "steps": nav.steps,
            "final": [nav.last.pose.x, nav.last.pose.y],
            "trajectory": nav.trajectory,
        }
    finally:
        sim.close()


def explore(
    memory: MemoryOpt,
    env: EnvOpt = "vizdoom:freedoom2/MAP02",
    steps: Annotated[int, STEPS, typer.Option(help="control steps (one step = 2 Doom tics)")] = 3000,
    embedder: Annotated[str, typer.Option(help="embedder spec for the new memory")] = "offline",
    png: Annotated[Path | None, PICTURE, typer.Option(help="also draw the map here")] = None,
    keyframe_dist: Annotated[float, DISTANCE, typer.Option(help="metres moved between keyframes")] = 2.0,
    keyframe_turn: Annotated[float, ANGLE, typer.Option(help="degrees turned between keyframes")] = 45.0,
    force: Force = False,
    json_out: JsonOpt = False,
) -> None:
    """Phase I: explore with frontiers, build the occupancy map and the memory."""
    import ravenmem
    from ravenmem.errors import InputError
    from ravenmem.nav.render import draw_map
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
            draw_map(grid, _layers(grid, mem, sim.name), png)
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


def demo(
    out: Annotated[Path, typer.Option("--out", help="output folder (memories, maps, report)")] = Path(
        "ravenmem-demo"
    ),
    maps: Annotated[
        str | None,
        typer.Option(help="comma-separated environments (default: synthetic:gallery and two Freedoom maps)"),
    ] = None,
    steps: Annotated[
        int | None, STEPS, typer.Option(help="exploration budget in control steps per map")
    ] = None,
    queries: Annotated[int, COUNT, typer.Option(help="object queries per map")] = 8,
    success_radius: Annotated[
        float, DISTANCE, typer.Option(help="metres from the nearest true instance")
    ] = 3.0,
    pictures: Annotated[
        str, typer.Option(help="image queries: view (rendered elsewhere) | sprite (from the WAD)")
    ] = "view",
    overwrite: Annotated[
        bool, typer.Option(help="replace an existing --out folder (default: write <out>-2, ... beside it)")
    ] = False,
    json_out: JsonOpt = False,
) -> None:
    """Explore a gallery of real photographs, then Freedoom maps, into memories; find objects by
    picture, by oracle perception, by text and at random, and drive to each answer (offline,
    CPU). An existing --out is kept: the run then writes <out>-2, <out>-3, ..."""
    from ravenmem.demo import DemoConfig, run_demo

    cfg = DemoConfig(
        out=str(out), queries=queries, success_radius=success_radius, overwrite=overwrite, pictures=pictures
    )
    if maps:
        cfg.maps = [m.strip() for m in maps.split(",") if m.strip()]
    if steps is not None:
        cfg.steps = steps
    report = run_demo(cfg, progress=_say)
    if json_out:
        sys.stdout.write(json.dumps(report.as_dict(), indent=2) + "\n")
    else:
        sys.stdout.write(report.table() + "\n")


def register(app: typer.Typer) -> None:
    """Add `map`, `navigate`, `explore` and `demo` to the main `ravenmem` command."""
    app.command("map")(map_cmd)
    app.command("navigate")(navigate)
    app.command("explore")(explore)
    app.command("demo")(demo)
