"""What the node publishes besides goals: `diagnostic_msgs/DiagnosticArray` of its frame counts,
`visualization_msgs/MarkerArray` of the memories and of each answer (evidence, goal, text), and
a log that says each reason once and then at most every `every` seconds with its count."""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from ..agent.schema import Answer

NS_MEMORIES, NS_EVIDENCE, NS_GOAL, NS_TEXT = "memories", "evidence", "goal", "answer"


class RateLimitedLog:
    """One line per reason at first, then at most one every `every` s with the count since."""

    def __init__(self, write: Callable[[str], None], every: float = 10.0) -> None:
        self.write = write
        self.every = every
        self._last: dict[str, tuple[float, int]] = {}
        self._lock = threading.Lock()

    def __call__(self, reason: str) -> None:
        now = time.monotonic()
        with self._lock:
            last, n = self._last.get(reason, (-math.inf, 0))
            if now - last < self.every:
                self._last[reason] = (last, n + 1)
                return
            self._last[reason] = (now, 0)
        more = f" (and {n} more since the last report)" if n else ""
        self.write(f"frame skipped or message refused: {reason}{more}")


def diagnostics(stamp: Any, counts: dict[str, Any], name: str = "ravenmem: frames") -> Any:
    """A DiagnosticArray with one status: received, stored, skipped by reason, queue depth,
    last frame age. WARN when frames stopped coming, or bad messages arrive."""
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue

    values = {
        "received": counts["received"],
        "stored": counts["stored"],
        "skipped": sum(counts["skipped"].values()),
        "waiting for a pose": counts["pending"],
        "queue depth": counts["in_writer"],
        "lost in transport": counts["lost_in_transport"],  # sequence gaps: never reached the node
        "lost (reported by DDS)": counts["lost_reported_by_dds"],
        "poses": counts["poses"],
        "last frame age (s)": "" if counts["last_frame_age"] is None else f"{counts['last_frame_age']:.2f}",
    }
    values |= {f"skipped: {k}": v for k, v in sorted(counts["skipped"].items())}
    values |= {f"bad message: {k}": v for k, v in sorted(counts["bad_messages"].items())}
    age = counts["last_frame_age"]
    stale = age is not None and age > 5.0
    status = DiagnosticStatus(
        level=DiagnosticStatus.WARN if stale or counts["bad_messages"] else DiagnosticStatus.OK,
        name=name,
        message=f"no frames for {age:.0f} s" if stale else f"{counts['stored']} stored",
        hardware_id="ravenmem",
        values=[KeyValue(key=k, value=str(v)) for k, v in values.items()],
    )
    return DiagnosticArray(header=_header(stamp, ""), status=[status])


def _header(stamp: Any, frame: str) -> Any:
    from std_msgs.msg import Header

    return Header(stamp=stamp, frame_id=frame)


def _color(r: float, g: float, b: float, a: float = 0.9) -> Any:
    from std_msgs.msg import ColorRGBA

    return ColorRGBA(r=r, g=g, b=b, a=a)


def memory_markers(stamp: Any, frame: str, points: list[list[float]]) -> Any:
    """The memories as one sphere list (id, t, x, y, yaw rows of `Service.trajectory`)."""
    from geometry_msgs.msg import Point
    from visualization_msgs.msg import Marker, MarkerArray

    m = Marker(header=_header(stamp, frame), ns=NS_MEMORIES, id=0, type=Marker.SPHERE_LIST)
    m.action = Marker.ADD
    m.pose.orientation.w = 1.0
    m.scale.x = m.scale.y = m.scale.z = 0.08
    m.color = _color(0.2, 0.6, 1.0, 0.7)
    m.points = [Point(x=float(p[2]), y=float(p[3]), z=0.0) for p in points]
    return MarkerArray(markers=[m])


def answer_markers(stamp: Any, frame: str, answer: Answer, goal: dict[str, Any] | None) -> Any:
    """An answer (typed: this is where it becomes messages): its evidence (spheres), its goal
    (an arrow) and its text (above the goal, or the first evidence). Markers of an earlier
    answer are replaced (same ids; DELETE when none)."""
    from geometry_msgs.msg import Point
    from visualization_msgs.msg import Marker, MarkerArray

    out = []
    ev = Marker(header=_header(stamp, frame), ns=NS_EVIDENCE, id=0, type=Marker.SPHERE_LIST)
    ev.pose.orientation.w = 1.0
    ev.scale.x = ev.scale.y = ev.scale.z = 0.2
    ev.color = _color(1.0, 0.8, 0.1)
    ev.points = [Point(x=float(e.x), y=float(e.y), z=0.2) for e in answer.evidence]
    ev.action = Marker.ADD if ev.points else Marker.DELETE
    out.append(ev)
    arrow = Marker(header=_header(stamp, frame), ns=NS_GOAL, id=0, type=Marker.ARROW)
    arrow.scale.x, arrow.scale.y, arrow.scale.z = 0.6, 0.12, 0.12
    arrow.color = _color(0.1, 0.9, 0.3)
    if goal:
        p, q = goal["pose"]["position"], goal["pose"]["orientation"]
        arrow.pose.position.x, arrow.pose.position.y = float(p["x"]), float(p["y"])
        arrow.pose.orientation.z, arrow.pose.orientation.w = float(q["z"]), float(q["w"])
    else:
        arrow.pose.orientation.w = 1.0
    arrow.action = Marker.ADD if goal else Marker.DELETE
    out.append(arrow)
    text = Marker(header=_header(stamp, frame), ns=NS_TEXT, id=0, type=Marker.TEXT_VIEW_FACING)
    text.scale.z = 0.25
    text.color = _color(1.0, 1.0, 1.0)
    text.text = answer.text[:200]
    anchor = arrow.pose.position if goal else (ev.points[0] if ev.points else None)
    text.pose.orientation.w = 1.0
    if anchor is not None:
        text.pose.position.x, text.pose.position.y, text.pose.position.z = anchor.x, anchor.y, 0.8
    text.action = Marker.ADD if anchor is not None and text.text else Marker.DELETE
    out.append(text)
    return MarkerArray(markers=out)
