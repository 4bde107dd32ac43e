"""The words the models get: role, what the memory holds, the tools, and the answer format."""

from __future__ import annotations

from ..timeparse import fmt_time
from .questions import fmt_duration

ANSWER_FORMAT = """When you answer, reply with ONLY this JSON object (no other text):
{"question_type": "position" | "time" | "binary" | "text" | "duration",
 "answer": "one or two sentences for the user",
 "evidence": [memory ids that support the answer, the most relevant first, e.g. 12],
 "position": null or [x, y, z] in metres in the map frame, where to go to see the thing (null = the camera position of the first evidence memory),
 "yaw_deg": null or the heading to face it, in degrees counter-clockwise from the map x axis like the yaw in the listings (null = the camera heading of the first evidence memory),
 "time": null or the time as written in the memory listings (null = time of the first evidence memory),
 "duration_s": null or seconds (for "how long" questions),
 "yes": null or true or false (for yes/no questions),
 "found": true or false (false when the memories do not show what was asked),
 "reasoning": "a short explanation"}
For "where" questions put the memory whose camera saw the thing best first in evidence; for
"when did I last" questions, the latest memory that shows it; for "first", the earliest; for
"now" questions, the latest sighting at the place where it is now."""

CHANGES = """The world changes: things get moved or taken away, and old memories still show them where
they were. For questions about the present ("where is it now?", "is it still there?", "where
is it currently?"), call search_text (or search_image) with latest=true: it lists the latest
sighting at each place the thing was seen, newest place first, each with a verdict from the
robot's later visits: "still there" (seen there again later), "not revisited" (nothing has
looked at that place since), "moved" (the place was looked at again without it, and it was
seen elsewhere since) or "gone" (looked at again without it, not seen anywhere since), with
the later views that no longer show it, and the thing's status now. Answer "now" questions
from the newest place that is neither moved nor gone; when the status is gone, say where and
when it was last seen and that the place was looked at again without it (found: false). For
questions about the past ("where was it at the start?", "at 10:00?"), use before/after (with
latest=true and before=T for "where was it at T?"), not the newest sighting."""

NO_PICTURES = (
    "the model saw no pictures: each memory was described as text (time, pose, score, the text "
    "seen in it and labels of what its picture shows)"
)

JSON_TOOL_PROTOCOL = """You cannot call functions directly. To use a tool, reply with ONLY:
{"tool": "<tool name>", "arguments": {...}}
and wait for the results. Tools:
"""


def system_prompt(
    count: int,
    span: tuple[float, float],
    tools_listing: str | None,
    max_tool_calls: int,
    images: bool = True,
    scores: bool = True,
    query_image: bool = False,
    latest: bool = False,
    captions: bool = True,
) -> str:
    """The system message; `tools_listing` is set in the JSON-in-prompt protocol only;
    `latest`: the text/image tools offer the latest mode (a world that changes); without
    `images`, memories are shown as their `captions` or else as labels of their pictures."""
    t0, t1 = span
    seen = "camera images" if images else "text captions of camera images"
    if not images and not captions:
        seen = "camera images described in words (labels of what each picture shows)"
    lines = [
        "You are the memory of a mobile robot. You answer questions about what the robot saw, "
        "where (map coordinates in metres, yaw in degrees) and when (UTC).",
        f"The memory holds {count} observations ({seen} with time and camera pose) from "
        f"{fmt_time(t0)} to {fmt_time(t1)} ({fmt_duration(t1 - t0)}). 'Now' is {fmt_time(t1)}.",
    ]
    if max_tool_calls > 0:
        tools = (
            f"Search the memory with the tools (at most {max_tool_calls} tool calls in total), "
            "look at the retrieved memories, then answer."
        )
        if scores:
            tools += " Scores are similarities: higher is a better match."
        if query_image:
            tools += " search_image without memory_id searches with the image attached to the question."
        lines.append(tools)
        if latest:
            lines.append(CHANGES)
    if tools_listing:
        lines.append(JSON_TOOL_PROTOCOL + tools_listing)
    lines.append(ANSWER_FORMAT)
    return "\n\n".join(lines)


def budget_spent(max_tool_calls: int) -> str:
    return (
        f"You have used all {max_tool_calls} tool calls. Do not call tools any more: answer now "
        "from the memories shown, with only the JSON answer object."
    )


def reask(reason: str) -> str:
    return f"Your last reply could not be used: {reason}. Reply again with ONLY the JSON answer object described above."
