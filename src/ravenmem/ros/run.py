"""`ravenmem ros run` (also `python -m ravenmem.ros.run`): the process around the ROS 2 node.

    ravenmem ros setup                      # once: builds ravenmem_msgs into this environment
    ravenmem ros run --memory robot.mem --create --ros-args \\
        -p image_topic:=/camera/color/image_raw -p odom_topic:=/odom -r __ns:=/bot1

Parses ravenmem's own arguments (everything from `--ros-args` on is rclpy's), starts rclpy,
turns SIGINT and SIGTERM into a clean stop, and runs the node (`ros.node.RavenmemNode`) plain
or, with `--lifecycle`, managed (`ros.lifecycle`). Apart from both so that neither imports the
other's entry point.
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
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from ..errors import InputError, MissingDependencyError, RavenmemError
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
    from rclpy.executors import MultiThreadedExecutor
    from rclpy.signals import SignalHandlerOptions

    with _stderr_held() as said:  # rcl logs a bad argument itself before raising
        try:  # a malformed --ros-args (rcl parses it) is the user's input: one line, exit 2
            rclpy.init(args=["ravenmem", *ros_args], signal_handler_options=SignalHandlerOptions.NO)
        except Exception as e:
            said["show"] = False
            raise InputError(f"--ros-args: {' '.join(str(e).split())}") from None
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    if args.lifecycle:
        from .lifecycle import run_managed

        run_managed(args.memory, args.create, stop)
        return
    node = made_node(lambda: rclpy.create_node("ravenmem"))
    service = None
    try:
        settings = NodeSettings.declare(node)
        service = open_service(args.memory, args.create, settings)
        ros_node = RavenmemNode(node, settings, service)
        service.attach(ros_node)
        service.warm_up()  # the embedder loaded and run once: the first search is as fast as the next
        executor = MultiThreadedExecutor(num_threads=4)
        executor.add_node(node)
        node.get_logger().info(f"ravenmem: {args.memory} ({service.mem.count()} memories), ready")
        while not stop.is_set() and rclpy.ok():
            executor.spin_once(timeout_sec=0.1)
        node.get_logger().info("stopping: storing the frames already taken")
        ros_node.stop_intake()
        executor.shutdown(timeout_sec=1.0)
        ros_node.finish()  # stores what was queued, notes the run, closes the memory
        service = None
    finally:
        if service is not None:
            service.close()
        node.destroy_node()
        if rclpy.ok():
            rclpy.shutdown()


if __name__ == "__main__":
    try:
        main()
    except RavenmemError as e:  # one line, as the ravenmem command prints it
        sys.stderr.write(f"error: {e}\n")
        sys.exit(2)
