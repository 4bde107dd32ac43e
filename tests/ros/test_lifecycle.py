"""The managed node (`ravenmem ros run --lifecycle`) on a real ROS 2 graph: the node in its own
process, driven here through lifecycle_msgs' ChangeState and GetState services as
nav2_lifecycle_manager drives its nodes; the camera and odometry published from this process,
so that one publisher lives across a deactivation. The memory opens at configure, frames are
stored only while active, and cleanup leaves a closed memory another process may write."""

from __future__ import annotations

import json
import os
import subprocess
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from PIL import Image as PILImage

import ravenmem
from ravenmem.memory.folder import is_memory
from tests.cli.helpers import run_cli
from tests.conftest import TUM, tum_data
from tests.ros.ros_pub import tum
from tests.ros.rosgraph import Client, graph_env, launch, require_ros, stop, wait_for

pytestmark = pytest.mark.ros
DOMAIN = 119  # this module's ROS domain (other modules of tests/ros use others)
NODE = "/ravenmem"


@pytest.fixture(scope="module")
def ros() -> None:
    require_ros()


@pytest.fixture(scope="module")
def recording(ros: None) -> Path:
    """The TUM recording, once ROS 2 is known to be here."""
    return tum_data()


def _launch(mem: Path, log: Path, *ros_args: str, create: bool = True) -> subprocess.Popen[str]:
    """`ravenmem ros run --lifecycle`, once it says it is ready (unconfigured)."""
    args = ["-m", "ravenmem.cli.main", "ros", "run", "--memory", str(mem), "--lifecycle"]
    args += ["--create"] if create else []
    return launch([*args, "--ros-args", *ros_args], DOMAIN, log, "the managed node to start", 300)


def _change(client: Client, transition: int) -> bool:
    """ChangeState on the node: whether the transition succeeded."""
    from lifecycle_msgs.msg import Transition
    from lifecycle_msgs.srv import ChangeState

    request = ChangeState.Request(transition=Transition(id=transition))
    return bool(client.call(ChangeState, f"{NODE}/change_state", request).success)  # type: ignore[attr-defined]


def _state(client: Client) -> str:
    from lifecycle_msgs.srv import GetState

    return str(client.call(GetState, f"{NODE}/get_state", GetState.Request()).current_state.label)  # type: ignore[attr-defined]


def _diag(box: list[Any]) -> dict[str, str]:
    return {kv.key: kv.value for kv in box[-1].status[0].values} if box else {}


def _settled(diag: list[Any], received: int) -> dict[str, str]:
    """Wait until the node received `received` images and every one is stored or skipped."""
    wait_for(
        lambda: (
            _diag(diag).get("received") == str(received)
            and _diag(diag).get("waiting for a pose") == "0"
            and _diag(diag).get("queue depth") == "0"
        ),
        120,
        f"the node to settle {received} frames",
        show=lambda: _diag(diag),
    )
    return _diag(diag)


class Camera:
    """The TUM recording (160x120 rgb8 images, odometry from its ground truth) published from
    the test's node by one publisher each, as a robot's camera driver keeps publishing whatever
    state the memory node is in."""

    def __init__(self, node: Any, frames: int) -> None:
        from nav_msgs.msg import Odometry
        from rclpy.qos import QoSProfile, ReliabilityPolicy
        from sensor_msgs.msg import Image

        qos = QoSProfile(depth=200, reliability=ReliabilityPolicy.RELIABLE)
        self.images = node.create_publisher(Image, "/camera/image_raw", qos)
        self.odom = node.create_publisher(Odometry, "/odom", qos)
        self.rgb, self.gt = tum(TUM, frames)
        self.gi = 0

    def matched(self) -> bool:
        return bool(self.images.get_subscription_count() and self.odom.get_subscription_count())

    def wait_matched(self, what: str) -> None:
        """Until the node's subscriptions matched these publishers, and a second more (both
        ends have matched: as tests/ros/ros_pub.py waits)."""
        import time

        wait_for(self.matched, 60, what)
        time.sleep(1.0)

    def send(self, first: int, n: int) -> None:
        """Frames first..first+n-1, each after the poses up to 50 ms past it, at about 30 Hz."""
        import time

        for t, path in self.rgb[first : first + n]:
            while self.gi < len(self.gt) and self.gt[self.gi, 0] <= t + 0.05:
                self.odom.publish(self._odometry(self.gt[self.gi]))
                self.gi += 1
            self.images.publish(self._image(t, path))
            time.sleep(1 / 30)

    @staticmethod
    def _stamp(msg: Any, t: float) -> None:
        msg.header.stamp.sec = int(t)
        msg.header.stamp.nanosec = int(round((t - int(t)) * 1e9)) % 1_000_000_000

    def _odometry(self, row: np.ndarray) -> Any:
        from nav_msgs.msg import Odometry

        m = Odometry()
        self._stamp(m, float(row[0]))
        m.header.frame_id, m.child_frame_id = "odom", "base_link"
        p = m.pose.pose
        p.position.x, p.position.y, p.position.z = (float(v) for v in row[1:4])
        o = p.orientation
        o.x, o.y, o.z, o.w = (float(v) for v in row[4:8])
        return m

    def _image(self, t: float, path: Path) -> Any:
        from sensor_msgs.msg import Image

        with PILImage.open(path) as im:
            arr = np.asarray(im.convert("RGB").resize((160, 120)))
        msg = Image(height=120, width=160, encoding="rgb8", step=480, data=arr.tobytes())
        self._stamp(msg, t)
        msg.header.frame_id = "camera_link"
        return msg


def test_configure_activate_deactivate_cleanup_then_shutdown(recording: Path, tmp_path: Path) -> None:
    from diagnostic_msgs.msg import DiagnosticArray
    from lifecycle_msgs.msg import Transition as T
    from ravenmem_msgs.srv import Ask, Search

    mem, log = tmp_path / "robot.mem", tmp_path / "node.log"
    node = _launch(
        mem,
        log,
        *("-p", "image_qos:=reliable", "-p", "image_transport:=raw", "-p", "keyframes:=all"),
        *("-p", "diagnostics_period:=0.5", "-p", "markers_period:=0"),
    )
    client = Client(DOMAIN)
    try:
        diag = client.collect(DiagnosticArray, "/diagnostics")
        cam = Camera(client.node, 50)
        assert _state(client) == "unconfigured"
        assert not mem.exists()  # nothing is opened before configure
        assert _change(client, T.TRANSITION_CONFIGURE)
        assert _state(client) == "inactive" and is_memory(mem)
        assert _change(client, T.TRANSITION_ACTIVATE) and _state(client) == "active"
        cam.wait_matched("the node to subscribe to the camera and odometry")
        cam.send(0, 20)
        d = _settled(diag, 20)
        first = int(d["stored"])
        assert first >= 2 and first + int(d["skipped"]) == 20, d
        found = client.call(Search, f"{NODE}/search", Search.Request(tool="time", query="2011-05-10", k=3))
        assert found.error == "" and len(found.memories) == 3  # type: ignore[attr-defined]
        assert client.call(Ask, f"{NODE}/ask", Ask.Request(question="where is the desk?")).found  # type: ignore[attr-defined]

        assert _change(client, T.TRANSITION_DEACTIVATE) and _state(client) == "inactive"
        wait_for(lambda: not cam.images.get_subscription_count(), 60, "the image subscription to go")
        cam.send(20, 10)  # nobody takes them: not stored
        # inactive: questions are answered from the memory, navigating is refused
        assert client.call(Ask, f"{NODE}/ask", Ask.Request(question="where is the desk?")).found  # type: ignore[attr-defined]
        drive = client.call(Ask, f"{NODE}/ask", Ask.Request(question="where is the desk?", navigate=True))
        assert not drive.found and "inactive" in drive.reason, drive.reason  # type: ignore[attr-defined]
        assert drive.goal.header.frame_id == ""  # type: ignore[attr-defined]

        # active again, the same publisher: the 10 images sent meanwhile are not "lost"
        assert _change(client, T.TRANSITION_ACTIVATE)
        cam.wait_matched("the node to subscribe again")
        cam.send(30, 10)
        d = _settled(diag, 30)
        stored = int(d["stored"])
        assert d["lost in transport"] == "0" and stored > first, d
        assert stored + int(d["skipped"]) == 30, d

        assert _change(client, T.TRANSITION_DEACTIVATE) and _change(client, T.TRANSITION_CLEANUP)
        assert _state(client) == "unconfigured"
        # closed: readable by another process, and free to be written by one
        info = run_cli("info", "--memory", str(mem), "--json", env=graph_env(DOMAIN))
        assert info.returncode == 0 and json.loads(info.stdout)["memories"] == stored, info.stderr
        with ravenmem.open(mem, writable=True) as m:  # takes the writer lock without waiting
            assert m.count() == stored and m.frame_id == "odom"
        runs = [
            r for r in json.loads((mem / "memory.json").read_text())["ingests"] if r.get("source") == "ros"
        ]
        assert len(runs) == 1
        counts = runs[0]["counts"]
        assert counts["received"] == 30 and counts["stored"] == stored and counts["lost_in_transport"] == 0
        assert counts["pending"] == 0 and counts["in_writer"] == 0

        # configured again (the memory reopens) and active; shut down as soon as the frames
        # arrived: the ones it took are stored before the process exits
        assert _change(client, T.TRANSITION_CONFIGURE) and _change(client, T.TRANSITION_ACTIVATE)
        cam.wait_matched("the node to subscribe after configuring again")
        cam.send(40, 10)
        wait_for(lambda: _diag(diag).get("received") == "10", 60, "the node to take 10 frames")
        assert _change(client, T.TRANSITION_ACTIVE_SHUTDOWN)
        node.wait(60)
    finally:
        client.close()
        text = stop(node, log)
    assert node.returncode == 0, text[-3000:]
    assert "Traceback" not in text and " failed: " not in text, text[-3000:]
    runs = [r for r in json.loads((mem / "memory.json").read_text())["ingests"] if r.get("source") == "ros"]
    again = runs[1]["counts"]
    assert len(runs) == 2 and again["received"] == 10 and again["stored"] >= 1, again
    assert again["stored"] + sum(again["skipped"].values()) == 10 and again["in_writer"] == 0, again
    with ravenmem.open(mem, writable=True) as m:
        assert m.count() == stored + again["stored"]


def test_a_failed_configure_is_one_line_and_the_node_stays_unconfigured(ros: None, tmp_path: Path) -> None:
    from lifecycle_msgs.msg import Transition as T
    from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue
    from rcl_interfaces.srv import SetParameters

    mem, log = tmp_path / "missing.mem", tmp_path / "node.log"
    node = _launch(mem, log, "-p", "image_transport:=jpeg", create=False)
    client = Client(DOMAIN)

    def failures() -> list[str]:
        return [ln for ln in log.read_text().splitlines() if "] [ravenmem]: configure failed" in ln]

    try:
        assert _state(client) == "unconfigured"
        # a parameter the node cannot use: set right (declared before configure), tried again
        assert not _change(client, T.TRANSITION_CONFIGURE)
        assert "configure failed: image_transport: one of auto, raw, compressed, got 'jpeg'" in failures()[0]
        raw = ParameterValue(type=ParameterType.PARAMETER_STRING, string_value="raw")
        request = SetParameters.Request(parameters=[Parameter(name="image_transport", value=raw)])
        assert client.call(SetParameters, f"{NODE}/set_parameters", request).results[0].successful  # type: ignore[attr-defined]
        assert not _change(client, T.TRANSITION_CONFIGURE)
        assert _state(client) == "unconfigured"
        said = failures()
        assert len(said) == 2 and f"configure failed: no memory at {mem}" in said[1], said
        # the memory appears, but this process writes it: refused too, in one line
        held = ravenmem.create(mem)  # holds the writer lock
        try:
            assert not _change(client, T.TRANSITION_CONFIGURE)
            assert _state(client) == "unconfigured"
        finally:
            held.close()
        said = failures()
        assert len(said) == 3 and "configure failed:" in said[2] and f"pid {os.getpid()}" in said[2], said
        # free: configured again, the node opens it
        assert _change(client, T.TRANSITION_CONFIGURE) and _state(client) == "inactive"
    finally:
        client.close()
        text = stop(node, log)  # SIGTERM while inactive: the memory is closed
    assert node.returncode == 0, text[-3000:]
    assert "Traceback" not in text, text[-3000:]
    with ravenmem.open(mem, writable=True) as m:  # its writer lock was released
        assert m.count() == 0
