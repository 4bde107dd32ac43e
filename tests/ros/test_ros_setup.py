"""`ravenmem ros setup` as a user runs it: builds ravenmem_msgs (and tf2_msgs, nav2_msgs when
missing) into the environment, twice (the second does nothing), after which a fresh Python with
nothing sourced or exported imports the types; what is missing is named in one line."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from tests.cli.helpers import assert_one_line_error, run_cli
from tests.ros.rosgraph import require_ros

pytestmark = pytest.mark.ros


def test_setup_twice_then_the_types_import_with_nothing_sourced() -> None:
    import importlib.util

    if importlib.util.find_spec("rclpy") is None:
        require_ros()
    first = run_cli("ros", "setup", "--json", timeout=1200)
    assert first.returncode == 0, first.stderr[-3000:]
    done = json.loads(first.stdout)["packages"]
    assert set(done) == {"ravenmem_msgs", "tf2_msgs", "nav2_msgs"}
    assert set(done.values()) <= {"built", "up to date", "installed already"}
    second = run_cli("ros", "setup", "--json", timeout=600)
    assert second.returncode == 0, second.stderr[-3000:]
    assert set(json.loads(second.stdout)["packages"].values()) <= {"up to date", "installed already"}
    assert "building" not in second.stderr
    # a fresh interpreter, none of ROS's variables set: the types import and make a message
    env = {
        k: v
        for k, v in os.environ.items()
        if not k.startswith(("AMENT_", "ROS_", "COLCON_", "_ROS_WHEELS"))
        and k not in ("LD_LIBRARY_PATH", "CMAKE_PREFIX_PATH", "PYTHONPATH")
    }
    code = (
        "from ravenmem_msgs.srv import Ask, Search\n"
        "from ravenmem_msgs.action import Ask as AskAction\n"
        "from ravenmem_msgs.msg import Memory\n"
        "from tf2_msgs.msg import TFMessage\n"
        "from nav2_msgs.action import NavigateToPose\n"
        "r = Ask.Request(question='where is the mug?', navigate=True)\n"
        "print(r.question, Search.Response().error == '', AskAction.Feedback().stage == '',"
        " NavigateToPose.Goal().pose.header.frame_id == '', len(TFMessage().transforms))\n"
    )
    r = subprocess.run(
        [sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=120, cwd="/"
    )
    assert r.returncode == 0, r.stderr[-3000:]
    assert r.stdout.split() == ["where", "is", "the", "mug?", "True", "True", "True", "0"]


def test_setup_names_what_is_missing(tmp_path: Path) -> None:
    """Without cmake and a compiler on PATH a build that is needed (--force) stops at once with
    one line naming them; nothing installed is touched."""
    require_ros()
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    (bin_dir / "python").symlink_to(sys.executable)
    r = run_cli("ros", "setup", "--force", env={"PATH": str(bin_dir), "CXX": ""}, timeout=120)
    line = assert_one_line_error(r)
    assert "cmake" in line and "C++ compiler" in line
    assert "rclpy" not in line  # the extra is here: not named
