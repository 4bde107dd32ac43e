"""A camera + pose publisher on a real ROS 2 graph (rclpy), for the node's tests and the benchmark:
the TUM recording's frames as `sensor_msgs/Image` + `nav_msgs/Odometry`, or as
`CompressedImage` (the JPEG files as they are) + /tf and /tf_static, at a given rate. Waits for
the node's subscriptions before the first frame, and prints one JSON line at the end:
{"images": N, "poses": M}.

    python tests/ros/ros_pub.py --data DIR --frames 30 --mode raw --rate 30 [--ros-args ...]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
from PIL import Image as PILImage


def tum(data: Path, frames: int) -> tuple[list[tuple[float, Path]], np.ndarray]:
    rgb = []
    for line in (data / "rgb.txt").read_text().splitlines():
        if line and not line.startswith("#"):
            t, f = line.split()[:2]
            rgb.append((float(t), data / f))
    gt = np.array(
        [
            [float(v) for v in ln.split()]
            for ln in (data / "groundtruth.txt").read_text().splitlines()
            if ln and not ln.startswith("#")
        ]
    )
    # longer than the recording: played again, its stamps shifted past the end each time
    span = rgb[-1][0] - rgb[0][0] + 1 / 30
    loops = -(-frames // len(rgb))
    rgb = [(t + k * span, f) for k in range(loops) for t, f in rgb][:frames]
    gt = np.concatenate([gt + np.array([k * span] + [0.0] * 7) for k in range(loops)])
    return rgb, gt


def main() -> None:
    argv = sys.argv[1:]
    ros_args = argv[argv.index("--ros-args") :] if "--ros-args" in argv else []
    ap = argparse.ArgumentParser()
    ap.add_argument("--data", type=Path, required=True)
    ap.add_argument("--frames", type=int, default=30)
    ap.add_argument("--mode", choices=("raw", "compressed"), default="raw")
    ap.add_argument("--rate", type=float, default=30.0)
    ap.add_argument("--image-topic", default="camera/image_raw")
    ap.add_argument("--second-camera", default="", help="also publish each frame on this image topic")
    ap.add_argument("--pose-reliability", choices=("reliable", "best_effort"), default="reliable")
    ap.add_argument("--size", default="", help="WxH to resize to (raw mode), e.g. 640x480")
    ap.add_argument("--bad", action="store_true", help="also send one bad message of each kind")
    ap.add_argument("--wait", type=float, default=30.0, help="seconds to wait for the subscriber")
    ap.add_argument(
        "--alone",
        type=float,
        default=0.0,
        help="send the first and the last frame this many seconds apart from the others (around a "
        "burst: the frames whose sequence numbers show a subscriber what it missed between them)",
    )
    args = ap.parse_args(argv[: len(argv) - len(ros_args)])

    import rclpy
    from geometry_msgs.msg import TransformStamped
    from nav_msgs.msg import Odometry
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import CameraInfo, CompressedImage, Image
    from tf2_msgs.msg import TFMessage

    rclpy.init(args=["ros_pub", *ros_args])
    node = rclpy.create_node("tum_camera")
    rel = ReliabilityPolicy.RELIABLE if args.pose_reliability == "reliable" else ReliabilityPolicy.BEST_EFFORT
    img_qos = QoSProfile(depth=50, reliability=ReliabilityPolicy.RELIABLE)
    topics = [args.image_topic, *([args.second_camera] if args.second_camera else [])]
    if args.mode == "raw":
        img_pubs = [node.create_publisher(Image, t, img_qos) for t in topics]
        pose_pub = node.create_publisher(Odometry, "odom", QoSProfile(depth=200, reliability=rel))
    else:
        img_pubs = [node.create_publisher(CompressedImage, t + "/compressed", img_qos) for t in topics]
        pose_pub = node.create_publisher(TFMessage, "/tf", QoSProfile(depth=200, reliability=rel))
        static = node.create_publisher(
            TFMessage,
            "/tf_static",
            QoSProfile(
                depth=10, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL
            ),
        )
        st = TransformStamped()
        st.header.frame_id, st.child_frame_id = "base_link", "camera_link"
        st.transform.rotation.w = 1.0
        static.publish(TFMessage(transforms=[st]))
    info_pub = node.create_publisher(CameraInfo, "camera/camera_info", 10)

    deadline = time.monotonic() + args.wait
    img_pub = img_pubs[0]

    def unmatched() -> bool:
        return any(p.get_subscription_count() == 0 for p in (*img_pubs, pose_pub))

    while time.monotonic() < deadline and unmatched():
        rclpy.spin_once(node, timeout_sec=0.1)
    if unmatched():
        sys.stderr.write("no subscriber for the images\n")
        sys.exit(3)
    time.sleep(1.0)  # both ends have matched

    rgb, gt = tum(args.data, args.frames)
    size = tuple(int(v) for v in args.size.split("x")) if args.size else None
    gi, sent_poses, period = 0, 0, 1.0 / args.rate

    def stamp(msg: object, t: float) -> None:
        msg.header.stamp.sec = int(t)  # type: ignore[attr-defined]
        msg.header.stamp.nanosec = int(round((t - int(t)) * 1e9)) % 1_000_000_000  # type: ignore[attr-defined]

    info = CameraInfo(width=640, height=480, distortion_model="plumb_bob")
    info.k = [517.3, 0.0, 318.6, 0.0, 516.5, 255.3, 0.0, 0.0, 1.0]
    info.header.frame_id = "camera_link"
    next_t = time.monotonic()
    for i, (t, path) in enumerate(rgb):
        while gi < len(gt) and gt[gi, 0] <= t + 0.05:
            row = gt[gi]
            gi += 1
            if args.mode == "raw":
                m = Odometry()
                stamp(m, row[0])
                m.header.frame_id, m.child_frame_id = "odom", "base_link"
                p = m.pose.pose
                p.position.x, p.position.y, p.position.z = row[1:4]
                p.orientation.x, p.orientation.y, p.orientation.z, p.orientation.w = row[4:8]
            else:
                tf = TransformStamped()
                stamp(tf, row[0])
                tf.header.frame_id, tf.child_frame_id = "odom", "base_link"
                tr, q = tf.transform.translation, tf.transform.rotation
                tr.x, tr.y, tr.z = row[1:4]
                q.x, q.y, q.z, q.w = row[4:8]
                m = TFMessage(transforms=[tf])
            pose_pub.publish(m)
            sent_poses += 1
        if args.mode == "raw":
            with PILImage.open(path) as im:
                rgb_im = im.convert("RGB")
                if size:
                    rgb_im = rgb_im.resize(size)
                arr = np.asarray(rgb_im)
            msg = Image(height=arr.shape[0], width=arr.shape[1], encoding="rgb8", step=arr.shape[1] * 3)
            msg.data = arr.tobytes()
        else:
            msg = CompressedImage(format="jpeg")
            msg.data = path.read_bytes()
        stamp(msg, t)
        msg.header.frame_id = "camera_link"
        for p in img_pubs:
            p.publish(msg)
        if i == 0:
            stamp(info, t)
            info_pub.publish(info)
        next_t += period
        if i in (0, len(rgb) - 2) and args.alone > 0:
            next_t = time.monotonic() + args.alone
        time.sleep(max(0.0, next_t - time.monotonic()))
    bad = 0
    if args.bad and args.mode == "raw":
        bad = send_bad(img_pub, pose_pub, info_pub, rgb[-1][0])
    time.sleep(0.5)
    images = len(rgb) * len(img_pubs) + bad
    print(json.dumps({"images": images, "bad_images": bad, "poses": sent_poses}), flush=True)
    node.destroy_node()
    rclpy.shutdown()


def send_bad(img_pub, pose_pub, info_pub, t: float) -> int:  # type: ignore[no-untyped-def]
    """One bad message of each kind: wrong encoding, 0x0, truncated data (images); a NaN pose and
    a zero quaternion (odometry); a CameraInfo without K. Returns the bad images sent."""
    from nav_msgs.msg import Odometry
    from sensor_msgs.msg import CameraInfo, Image

    images = [
        Image(height=4, width=4, encoding="yuv422_weird", step=8, data=bytes(32)),
        Image(height=0, width=0, encoding="rgb8", step=0, data=b""),
        Image(height=480, width=640, encoding="rgb8", step=1920, data=bytes(1000)),
    ]
    for im in images:
        im.header.stamp.sec = int(t)
        im.header.frame_id = "camera_link"
        img_pub.publish(im)
        time.sleep(0.05)
    nan = Odometry()
    nan.header.frame_id = "odom"
    nan.pose.pose.position.x = float("nan")
    nan.pose.pose.orientation.w = 1.0
    zero = Odometry()
    zero.header.frame_id = "odom"
    for m in (nan, zero):
        pose_pub.publish(m)
        time.sleep(0.05)
    info_pub.publish(CameraInfo(width=640, height=480))
    return len(images)


if __name__ == "__main__":
    main()
