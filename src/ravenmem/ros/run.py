"""`ravenmem ros run` (also `python -m ravenmem.ros.run`): the process around the ROS 2 node.

    ravenmem ros setup                      # once: builds ravenmem_msgs into this environment
    ravenmem ros run --memory robot.mem --create --ros-args \\
        -p image_topic:=/camera/color/image_raw -p odom_topic:=/odom -r __ns:=/bot1

Parses ravenmem's own arguments (everything from `--ros-args` on is rclpy's), starts rclpy,
turns SIGINT and SIGTERM into a clean stop, and runs the node (`ros.node.RavenmemNode`) plain
or, with `--lifecycle`, managed (`ros.lifecycle`), both spun by one loop (`spin_until_stopped`).
Apart from both so that neither imports the other's entry point.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import os
import signal
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

from ..errors import InputError, MissingDependencyError, RavenmemError, one_line
from ..threads import share_cores
from .node import RavenmemNode, made_node, open_service
from .params import NodeSettings


def _rclpy() -> Any:
    """rclpy and the interface packages, or a one-line error saying how to get them."""
    try:
        rclpy = importlib.import_module("rclpy")
    except ImportError as e:
        raise MissingDependencyError(
            f"rclpy is not importable ({e}): pip install 'ravenmem[ros]', or source /opt/ros/<distro>/setup.bash"
        ) from e
    try:
        importlib.import_module("ravenmem_msgs.srv")
    except ImportError as e:
        raise MissingDependencyError(
            f"ravenmem_msgs is not built ({e}): run `ravenmem ros setup` in this environment"
        ) from e
    return rclpy


@contextlib.contextmanager
def _stderr_held() -> Iterator[dict[str, bool]]:
    """Hold what C code writes to fd 2 meanwhile and write it out after, unless the caller set
    `show` False (it reports the failure in its own one line)."""
    sys.stderr.flush()
    saved = os.dup(2)
    state = {"show": True}
    with tempfile.TemporaryFile() as tmp:
        os.dup2(tmp.fileno(), 2)
        try:
            yield state
        finally:
            os.dup2(saved, 2)
            os.close(saved)
            tmp.seek(0)
            text = tmp.read()
            if text and state["show"]:
                os.write(2, text)


def split_ros_args(argv: list[str]) -> tuple[list[str], list[str]]:
    """(ravenmem's own arguments, the ROS arguments from `--ros-args` on)."""
    if "--ros-args" in argv:
        i = argv.index("--ros-args")
        return argv[:i], argv[i:]
    return argv, []


def main(argv: list[str] | None = None) -> None:
    """Run the node until SIGINT/SIGTERM, then store what was queued and return (exit 0)."""
    own, ros_args = split_ros_args(list(sys.argv[1:] if argv is None else argv))
    ap = argparse.ArgumentParser(prog="ravenmem ros run", description="ravenmem as a ROS 2 node")
    ap.add_argument("--memory", "-m", required=True, type=Path, help="memory folder")
    ap.add_argument("--create", action="store_true", help="create the memory when missing")
    ap.add_argument("--lifecycle", action="store_true", help="a managed node (ros.lifecycle)")
    args = ap.parse_args(own)
    share_cores()  # before torch or FAISS loads (ravenmem.threads)
    rclpy = _rclpy()
    from rclpy.signals import SignalHandlerOptions

    with _stderr_held() as said:  # rcl logs a bad argument itself before raising
        try:  # a malformed --ros-args (rcl parses it) is the user's input: one line, exit 2
            rclpy.init(args=["ravenmem", *ros_args], signal_handler_options=SignalHandlerOptions.NO)
        except Exception as e:
            said["show"] = False
            raise InputError(f"--ros-args: {one_line(e)}") from None
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    (_run_managed if args.lifecycle else _run_plain)(args.memory, args.create, stop)


@contextlib.contextmanager
def _node_up(make: Callable[[], Any]) -> Iterator[Any]:
    """The node `make()` makes (`node.made_node`), destroyed and rclpy shut down after."""
    import rclpy

    node = made_node(make)
    try:
        yield node
    finally:
        node.destroy_node()
        if rclpy.ok():
            rclpy.shutdown()


def spin_until_stopped(
    node: Any, stop: threading.Event, stopping: Callable[[], None], linger: Callable[[], float] = lambda: 0.0
) -> None:
    """Spin `node` on a 4-thread executor until `stop` is set (a signal, or the managed node's
    shutdown) or rclpy is shut down; then `linger()` seconds more (a reply still on its way
    reaches its caller); then `stopping()` while the executor still runs (the callbacks under
    way end meanwhile); then stop the executor."""
    import rclpy
    from rclpy.executors import MultiThreadedExecutor

    executor = MultiThreadedExecutor(num_threads=4)
    executor.add_node(node)
    while not stop.is_set() and rclpy.ok():
        executor.spin_once(timeout_sec=0.1)
    end = time.monotonic() + linger()
    while time.monotonic() < end and rclpy.ok():
        executor.spin_once(timeout_sec=0.1)
    stopping()
    executor.shutdown(timeout_sec=1.0)


def _run_plain(memory: Path, create: bool, stop: threading.Event) -> None:
    """The plain node: the memory open and frames taken from the start until `stop`; then the
    frames already taken are stored and the memory closed."""
    import rclpy

    with _node_up(lambda: rclpy.create_node("ravenmem")) as node:
        service = None
        try:
            settings = NodeSettings.declare(node)
            service = open_service(memory, create, settings)
            ros_node = RavenmemNode(node, settings, service)
            service.attach(ros_node)
            service.warm_up()  # the embedder loaded and run once: the first search is as fast as the next
            node.get_logger().info(f"ravenmem: {memory} ({service.mem.count()} memories), ready")

            def stopping() -> None:
                node.get_logger().info("stopping: storing the frames already taken")
                ros_node.stop_intake()

            spin_until_stopped(node, stop, stopping)
            ros_node.finish()  # stores what was queued, notes the run, closes the memory
            service = None
        finally:
            if service is not None:
                service.close()


def _run_managed(memory: Path, create: bool, stop: threading.Event) -> None:
    """The managed node (`ros.lifecycle`) until it is shut down (the transition) or stopped
    (`stop`: SIGINT, SIGTERM); the memory is closed either way."""
    from .lifecycle import LINGER_S, ManagedNode

    with _node_up(lambda: ManagedNode(memory, create, stop)) as node:
        node.get_logger().info(f"ravenmem: {memory}, managed: unconfigured (configure, then activate); ready")
        spin_until_stopped(node, stop, node.close, lambda: LINGER_S if node.finished else 0.0)


if __name__ == "__main__":
    try:
        main()
    except RavenmemError as e:  # one line, as the ravenmem command prints it
        sys.stderr.write(f"error: {e}\n")
        sys.exit(2)
