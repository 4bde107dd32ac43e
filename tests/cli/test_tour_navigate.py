"""The README tour's `ask --navigate` block, run as written: a simulated robot with depth explores
the demo's gallery into a memory with a map, then the tour's question is answered and planned on
that map; the goal is where the robot can see the game controller again."""

from __future__ import annotations

import json
import math
import re
import shlex
from pathlib import Path

from ravenmem.cli._console import rounded
from ravenmem.nav.goals import read_pose_stamped
from ravenmem.sim.base import create_env
from tests.cli.helpers import REPO, run_cli


def navigate_block() -> list[list[str]]:
    """The commands (argument lists, comments dropped) of the tour's bash block that uses
    `--navigate` (the README's "A quick tour" section)."""
    readme = (REPO / "README.md").read_text(encoding="utf-8")
    section = readme.split("## A quick tour", 1)[1].split("\n## ", 1)[0].split("\n### ", 1)[0]
    blocks = [b for b in re.findall(r"```bash\n(.*?)```", section, re.S) if "--navigate" in b]
    assert len(blocks) == 1, "the tour has one bash block that navigates"
    return [shlex.split(line, comments=True) for line in blocks[0].splitlines() if line.strip()]


def test_the_tours_navigate_block_plans_to_a_pose_that_sees_the_thing(tmp_path: Path) -> None:
    commands = navigate_block()
    assert [c[0] for c in commands] == ["ravenmem"] * len(commands)
    for args in commands[:-1]:
        r = run_cli(*args[1:], cwd=tmp_path, unset=("RAVENMEM_SERVER",))
        assert r.returncode == 0, r.stderr[-3000:]
    ask = commands[-1]
    assert ask[1] == "ask" and {"--offline", "--navigate", "--json"} <= set(ask)
    mem = Path(ask[ask.index("--memory") + 1])
    assert (tmp_path / mem / "map.npz").is_file()  # the exploration built a map as it went

    r = run_cli(*ask[1:], cwd=tmp_path, unset=("RAVENMEM_SERVER",))
    assert r.returncode == 0, r.stderr[-3000:]
    data = json.loads(r.stdout)
    assert data["found"] and not data["unsupported"] and data["map_id"] == "synthetic:gallery"
    nav = data["navigation"]
    assert nav["ok"] and nav["problem"] is None and nav["frame_id"] == "map", nav
    gx, gy, gyaw = nav["goal"]
    assert nav["waypoints"][-1] == [gx, gy] and nav["path_length_m"] > 0
    assert math.dist((gx, gy), data["position"][:2]) < 0.5  # where the robot stood when it saw it
    x, y, yaw, frame = read_pose_stamped(nav["pose_stamped"])
    assert (frame, x, y) == ("map", gx, gy) and math.isclose(yaw, gyaw, abs_tol=1e-9)

    # in words: the plan's line, then the same goal for Nav2 on the last line, rounded as
    # `navigate` rounds it (4 decimals; --json above keeps every digit)
    r = run_cli(*[a for a in ask[1:] if a != "--json"], cwd=tmp_path, unset=("RAVENMEM_SERVER",))
    assert r.returncode == 0, r.stderr[-3000:]
    lines = r.stdout.splitlines()
    assert any(ln.startswith("navigate: A* path") and f"to ({gx:.2f}, {gy:.2f})" in ln for ln in lines), (
        r.stdout
    )
    assert json.loads(lines[-1]) == rounded(nav["pose_stamped"])
    assert max(len(d) for d in re.findall(r"\.(\d+)", lines[-1])) <= 4, lines[-1]

    # the simulated robot, placed at the goal with its heading, sees the game controller
    env = create_env("synthetic:gallery")
    env.reset()
    (controller,) = [o for o in env.objects() if o.kind == "GameController"]
    assert controller.id in env.view_from(gx, gy, gyaw).visible_boxes
    assert math.dist((gx, gy), (controller.x, controller.y)) < 4.0
