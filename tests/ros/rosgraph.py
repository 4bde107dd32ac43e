"""Helpers of the tests on a real ROS 2 graph (rclpy + Fast DDS from the `ros` extra): whether
it is here, the environment of a graph of processes restricted to this host on its own domain."""

from __future__ import annotations

import importlib.util
import os
import subprocess
import sys
from pathlib import Path

import pytest

from tests.cli.helpers import REPO


def require_ros() -> None:
    """Skip (fail with RAVENMEM_REQUIRE_ROS=1, as CI sets it) when rclpy or the built
    interfaces are missing: `pip install -e '.[ros]' && ravenmem ros setup`."""
    missing = [
        m for m in ("rclpy", "ravenmem_msgs", "tf2_msgs", "nav2_msgs") if importlib.util.find_spec(m) is None
    ]
    if missing:
        why = f"ROS 2 not here ({', '.join(missing)} missing): pip install -e '.[ros]' && ravenmem ros setup"
        if os.environ.get("RAVENMEM_REQUIRE_ROS"):
            pytest.fail(why)
        pytest.skip(why)


def graph_env(domain: int) -> dict[str, str]:
    """A process's environment on ROS domain `domain`, discovery limited to this host."""
    env = dict(os.environ)
    env.update(
        ROS_DOMAIN_ID=str(domain),
        ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST",
        PYTHONPATH=os.pathsep.join([str(REPO / "src"), str(REPO)]),
        PYTHONUNBUFFERED="1",
    )
    env.pop("ROS_LOCALHOST_ONLY", None)
    return env


def start(args: list[str], domain: int, log: Path) -> subprocess.Popen[str]:
    """`python ARGS` on the graph, stdout and stderr into `log`."""
    f = log.open("w")
    return subprocess.Popen(
        [sys.executable, *args],
        env=graph_env(domain),
        stdout=f,
        stderr=subprocess.STDOUT,
        text=True,
        cwd=REPO,
    )


def launch(args: list[str], domain: int, log: Path, what: str, timeout: float = 180) -> subprocess.Popen[str]:
    """`start` a process of the graph and wait until it logs "ready" (it must still be running)."""
    proc = start(args, domain, log)
    wait_for(lambda: "ready" in log.read_text() or proc.poll() is not None, timeout, what)
    assert proc.poll() is None, f"{what} exited {proc.returncode}: {log.read_text()[-3000:]}"
    return proc


def launch_node(memory: Path, domain: int, log: Path, *ros_args: str) -> subprocess.Popen[str]:
    """`ravenmem ros run --memory MEMORY --create --ros-args ROS_ARGS`, once it is ready."""
    args = ["-m", "ravenmem.cli.main", "ros", "run", "--memory", str(memory), "--create"]
    return launch([*args, "--ros-args", *ros_args], domain, log, "the node to start", 300)


def launch_peer(what: str, domain: int, log: Path, *args: str) -> subprocess.Popen[str]:
    """A peer of tests/ros/ros_peers.py (`map`, `nav`), once it is ready."""
    return launch(
        [str(Path(__file__).parent / "ros_peers.py"), what, *args], domain, log, f"the {what} peer", 60
    )


class Client:
    """An rclpy node of the test process on `domain` (its own context), spun on a thread:
    subscriptions that collect what arrives, service and action calls with timeouts."""

    def __init__(self, domain: int, name: str = "test_client") -> None:
        import threading

        import rclpy
        from rclpy.executors import SingleThreadedExecutor

        os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
        self.context = rclpy.Context()
        rclpy.init(context=self.context, domain_id=domain)
        self.node = rclpy.create_node(name, context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.got: dict[str, list[object]] = {}
        self._thread = threading.Thread(target=self._spin, daemon=True)
        self._thread.start()

    def _spin(self) -> None:
        import contextlib

        with contextlib.suppress(Exception):  # the context shut down under it
            self.executor.spin()

    def collect(self, cls: type, topic: str, qos: object = 10) -> list[object]:
        box: list[object] = []
        self.got[topic] = box
        self.node.create_subscription(cls, topic, box.append, qos)
        return box

    def count(self, cls: type, topic: str, qos: object = 10) -> list[int]:
        """A plain subscriber that only counts what it receives ([n])."""
        box = [0]

        def one(_msg: object) -> None:
            box[0] += 1

        self.node.create_subscription(cls, topic, one, qos)
        return box

    def call(self, srv: type, name: str, request: object, timeout: float = 120.0) -> object:
        import threading

        client = self.node.create_client(srv, name)
        assert client.wait_for_service(timeout_sec=60), f"no service {name}"
        done = threading.Event()
        fut = client.call_async(request)
        fut.add_done_callback(lambda _f: done.set())
        assert done.wait(timeout), f"{name}: no reply in {timeout} s"
        return fut.result()

    def close(self) -> None:
        import rclpy

        self.executor.shutdown(timeout_sec=2)
        self.node.destroy_node()
        rclpy.shutdown(context=self.context)


def wait_for(cond, timeout: float, what: str, step: float = 0.2, show=None) -> None:  # type: ignore[no-untyped-def]
    """Wait until cond() is true (a condition on the graph, not a timing assertion); `show()`
    says what was there instead."""
    import time

    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if cond():
            return
        time.sleep(step)
    raise AssertionError(f"timed out waiting for {what}" + (f": {show()}" if show else ""))


def stop(proc: subprocess.Popen[str], log: Path, timeout: float = 120, sig: int = 15) -> str:
    """A signal (SIGTERM), wait, the exit code asserted 0 by the caller; the log's text."""
    if proc.poll() is None:
        proc.send_signal(sig)
        try:
            proc.wait(timeout)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
    return log.read_text(errors="replace")
