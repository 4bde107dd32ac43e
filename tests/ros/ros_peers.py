"""Other processes of the test graph: a map_server-like `/map` publisher (transient local) and a
NavigateToPose action server built from Nav2's interface (it accepts every goal, sends three
feedbacks, succeeds, and appends each goal it got to a JSON-lines file).

    python tests/ros/ros_peers.py map --origin -2,-2 --size 120 --resolution 0.05 [--ros-args ...]
    python tests/ros/ros_peers.py nav --log goals.jsonl [--ros-args ...]
"""

from __future__ import annotations

import argparse
import contextlib
import json
import sys
import time
from pathlib import Path


def main() -> None:
    argv = sys.argv[1:]
    ros_args = argv[argv.index("--ros-args") :] if "--ros-args" in argv else []
    ap = argparse.ArgumentParser()
    ap.add_argument("what", choices=("map", "nav"))
    ap.add_argument("--origin", default="-2,-2")
    ap.add_argument("--size", type=int, default=120)
    ap.add_argument("--resolution", type=float, default=0.05)
    ap.add_argument("--log", type=Path, default=None)
    ap.add_argument("--seconds", type=float, default=0.3, help="how long a drive takes")
    args = ap.parse_args(argv[: len(argv) - len(ros_args)])

    import rclpy
    from rclpy.executors import MultiThreadedExecutor

    rclpy.init(args=["peer", *ros_args])
    node = rclpy.create_node("map_server" if args.what == "map" else "bt_navigator")
    keep = publish_map(node, args) if args.what == "map" else serve_navigate(node, args.log, args.seconds)
    print("ready", flush=True)
    ex = MultiThreadedExecutor()
    ex.add_node(node)
    with contextlib.suppress(KeyboardInterrupt):
        ex.spin()
    del keep


def publish_map(node, args):  # type: ignore[no-untyped-def]
    from nav_msgs.msg import OccupancyGrid
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

    qos = QoSProfile(
        depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL
    )
    pub = node.create_publisher(OccupancyGrid, "map", qos)
    m = OccupancyGrid()
    m.header.frame_id = "odom"
    m.info.resolution = args.resolution
    m.info.width = m.info.height = args.size
    ox, oy = (float(v) for v in args.origin.split(","))
    m.info.origin.position.x, m.info.origin.position.y = ox, oy
    m.info.origin.orientation.w = 1.0
    cells = [0] * (args.size * args.size)  # free, with a wall on the border
    for i in range(args.size):
        for j in (0, args.size - 1):
            cells[i * args.size + j] = cells[j * args.size + i] = 100
    m.data = cells
    pub.publish(m)
    return pub


def serve_navigate(node, log: Path | None, seconds: float):  # type: ignore[no-untyped-def]
    from nav2_msgs.action import NavigateToPose
    from rclpy.action import ActionServer, CancelResponse
    from rclpy.callback_groups import ReentrantCallbackGroup

    def note(rec: dict) -> None:  # type: ignore[type-arg]
        if log is not None:
            with log.open("a") as f:
                f.write(json.dumps(rec) + "\n")

    def execute(handle):  # type: ignore[no-untyped-def]
        g = handle.request.pose
        note(
            {
                "frame_id": g.header.frame_id,
                "x": g.pose.position.x,
                "y": g.pose.position.y,
                "stamp": g.header.stamp.sec + g.header.stamp.nanosec * 1e-9,
            }
        )
        steps = max(3, round(seconds / 0.1))
        for i in range(steps):
            if handle.is_cancel_requested:
                handle.canceled()
                note({"canceled": True})
                return NavigateToPose.Result(error_code=0, error_msg="canceled")
            if i < 3:  # three feedbacks
                fb = NavigateToPose.Feedback()
                fb.distance_remaining = 3.0 - i
                handle.publish_feedback(fb)
            time.sleep(0.1)
        handle.succeed()
        return NavigateToPose.Result(error_code=0, error_msg="")

    return ActionServer(
        node,
        NavigateToPose,
        "navigate_to_pose",
        execute,
        cancel_callback=lambda _r: CancelResponse.ACCEPT,
        callback_group=ReentrantCallbackGroup(),
    )


if __name__ == "__main__":
    main()
