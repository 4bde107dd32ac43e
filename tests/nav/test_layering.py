"""The layering of DESIGN.md for the simulator, navigation, robot and ROS floors: arrows point down.

sim is a low floor (it knows types and registries, nothing of maps), nav sits above memory
(maps, A*, goals; it knows nothing of simulators or robots), robot sits above both. ros (the
ROS 2 messages, bags, links, node and services) sits over the memory, the agent, the planner
and the application core it attaches to (`runtime`, never `server`: HTTP is a sibling front
end); nothing below it imports it (the bag source is reached by its
registry name). Checked twice: every `import` statement in the source (module level and inside
functions), and what importing each package really pulls into a fresh interpreter.
"""

from __future__ import annotations

import ast
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

SRC = Path(__file__).resolve().parents[2] / "src" / "ravenmem"

# What each package may import from ravenmem (anything else is a sideways or upward arrow).
_GROUND = {
    "types",
    "errors",
    "registry",
    "fsio",
    "timeparse",
    "imageio",
    "progress",
    "threads",
    "refusal",
    "stamps",
    "spec",
}
_DATA = _GROUND | {"memory", "tools", "store", "embed", "ingest"}
ALLOWED = {
    "sim": _GROUND | {"sim"},
    "nav": _GROUND | {"memory", "tools", "nav"},
    "robot": _DATA | {"sim", "nav", "robot"},
    "runtime": _DATA | {"agent", "nav", "runtime"},
    "ros": _DATA | {"agent", "nav", "runtime", "ros"},
}
# packages below ros: none of them may import it
BELOW_ROS = (
    "types",
    "errors",
    "fsio",
    "memory",
    "store",
    "embed",
    "ingest",
    "agent",
    "nav",
    "runtime",
    "server",
    "sim",
    "robot",
)


def _ravenmem_imports(path: Path, package: str) -> set[str]:
    """Top-level ravenmem subpackages a module imports (absolute or relative, at any depth)."""
    tree = ast.parse(path.read_text())
    rel_parts = path.relative_to(SRC).with_suffix("").parts  # e.g. ("nav", "grid")
    out: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for a in node.names:
                if a.name.startswith("ravenmem."):
                    out.add(a.name.split(".")[1])
        elif isinstance(node, ast.ImportFrom):
            if node.level == 0:
                if node.module and node.module.startswith("ravenmem."):
                    out.add(node.module.split(".")[1])
                elif node.module == "ravenmem":
                    out.update(a.name for a in node.names)
                continue
            base = list(rel_parts[:-1])  # the module's package inside ravenmem
            up = node.level - 1
            base = base[: len(base) - up] if up else base
            target = base + (node.module.split(".") if node.module else [])
            if target:
                out.add(target[0])
            else:  # `from .. import x` at the top of ravenmem
                out.update(a.name for a in node.names)
    return out


@pytest.mark.parametrize("package", sorted(ALLOWED))
def test_imports_point_down(package: str) -> None:
    bad = {}
    for path in sorted((SRC / package).rglob("*.py")):
        wrong = _ravenmem_imports(path, package) - ALLOWED[package]
        if wrong:
            bad[str(path.relative_to(SRC))] = sorted(wrong)
    assert not bad, f"upward or sideways imports: {bad}"


def test_nothing_below_ros_imports_it() -> None:
    bad = {}
    for top in BELOW_ROS:
        paths = [SRC / f"{top}.py"] if (SRC / f"{top}.py").is_file() else sorted((SRC / top).rglob("*.py"))
        for path in paths:
            if "ros" in _ravenmem_imports(path, top):
                bad[str(path.relative_to(SRC))] = "ros"
    assert not bad, f"imports of ravenmem.ros from below it: {bad}"


def test_the_checker_sees_relative_and_lazy_imports() -> None:
    found = _ravenmem_imports(SRC / "nav" / "grid.py", "nav")
    assert {"types", "fsio", "errors"} <= found  # relative imports at module level are seen
    mission = SRC / "robot" / "mission.py"
    assert {"sim", "nav"} <= _ravenmem_imports(mission, "robot")  # lazy ones inside functions too


def test_importing_a_package_pulls_in_no_higher_floor() -> None:
    # the base: the memory facade (`import ravenmem` loads it on first use of `ravenmem.open`,
    # so it is imported here explicitly); on top of that, importing the simulator
    # must load no navigation, and navigation no simulator, robot, agent or ingest code.
    code = (
        "import importlib, json, sys\n"
        "def floors(mods):\n"
        "    return sorted({m.split('.')[1] for m in mods if m.startswith('ravenmem.')})\n"
        "import ravenmem, ravenmem.memory\n"
        "base = set(sys.modules)\n"
        "out = {'ravenmem': floors(base)}\n"
        "for pkg, mods in (('sim', ('vizdoom', 'synthetic', 'control', 'groundtruth', 'queries')),\n"
        "                  ('nav', ('mapping', 'planning', 'frontier', 'render', 'goals'))):\n"
        "    for name in [m for m in sys.modules if m not in base and m.startswith('ravenmem')]:\n"
        "        del sys.modules[name]\n"
        "    for m in mods:\n"
        "        importlib.import_module(f'ravenmem.{pkg}.{m}')\n"
        "    out[pkg] = floors(set(sys.modules) - base)\n"
        "print(json.dumps(out))\n"
    )
    env = dict(os.environ, PYTHONPATH=str(SRC.parent))
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, check=True)
    loaded = json.loads(r.stdout)
    assert not {"sim", "nav", "robot", "agent", "ingest"} & set(loaded["ravenmem"]), loaded["ravenmem"]
    assert loaded["sim"] == ["sim"], loaded["sim"]
    assert not {"sim", "robot", "agent", "ingest", "demo", "cli"} & set(loaded["nav"]), loaded["nav"]
    assert "nav" in loaded["nav"]
