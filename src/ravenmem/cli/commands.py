"""The commands other modules add to `ravenmem`, known without importing them.

`ravenmem search` should not pay for the agent, the evaluation or the service: the root command
(`main.LazyGroup`) imports a command's module (`ravenmem.cli.<module>`, whose `register(app)`
adds it) only when that command runs or shows its help. `ravenmem --help` lists them from here.

name -> (module, the first paragraph of its help), in the order `ravenmem --help` lists them.
tests/cli/test_cli_defaults.py checks this table against the commands the modules register.
"""

from __future__ import annotations

COMMANDS: dict[str, tuple[str, str]] = {
    "ask": (
        "agent",
        (
            "Answer a question from a memory: position, time, yes/no, duration or text, with "
            "evidence. Exit 1 when the question failed or its position is unsupported (see "
            "--allow-unsupported); with --navigate, exit 0 means a path to the answer was planned"
            " (1: answered, no path)."
        ),
    ),
    "caption": (
        "agent",
        (
            "Caption the memory in segments of consecutive keyframes with a VLM (the caption "
            "baseline); re-running captions only new segments."
        ),
    ),
    "map": (
        "nav",
        ("Build (if missing) or refresh the memory's occupancy map, draw it, export it for Nav2."),
    ),
    "navigate": (
        "nav",
        (
            "Plan with A* on the memory's own map to a position or to an answer "
            "(`nav.goals.goal_for`, as `ask --navigate` and the robot links do); print the path "
            "and the goal as a ROS PoseStamped in the memory's frame. Unknown or blocked goals "
            "snap to the nearest reachable cell that sees them. Exit 1 when there is no path, "
            "saying whether the start or the goal is the problem; with --json the plan is printed"
            " in every case (an input error too, exit 2)."
        ),
    ),
    "explore": (
        "nav",
        ("Phase I: explore with frontiers, build the occupancy map and the memory."),
    ),
    "demo": (
        "nav",
        (
            "Explore a gallery of real photographs, then Freedoom maps, into memories; find "
            "objects by picture, by oracle perception, by text and at random, and drive to each "
            "answer (offline, CPU). An existing --out is kept: the run then writes <out>-2, "
            "<out>-3, ..."
        ),
    ),
    "import": (
        "store",
        ("Import precomputed embeddings plus metadata (chunked, crash-safe; rerun to resume)."),
    ),
    "serve": (
        "serve",
        ("Serve a memory: HTTP API (/docs), a page for people (/), MCP (/mcp), live adds, a robot."),
    ),
    "mcp": (
        "serve",
        (
            "Serve a memory's tools (search_text, search_image, search_time, search_position, "
            'ask) to an MCP client over stdio, e.g. `{"command": "ravenmem", "args": ["mcp", "--'
            'memory", "DIR"]}`.'
        ),
    ),
    "forget": (
        "lifelong",
        (
            "Remove memories for good (index, metadata, thumbnails). Selectors combine: a memory "
            "goes when it matches every one given. Crash-safe: a kill leaves all of them or none."
        ),
    ),
    "consolidate": (
        "lifelong",
        (
            "Merge runs of near-duplicate memories (same place, consecutive in time) into one "
            "that keeps their time span and count, most similar first, to a budget or a "
            "similarity."
        ),
    ),
    "view": (
        "viz",
        ("Write a rerun recording of a memory: trajectory, keyframes with poses, and a query's hits."),
    ),
    "bench": (
        "bench",
        ("Measure the embedders, OCR and the store here; print keyframes/s and days of memory per GB."),
    ),
    "align": (
        "align",
        (
            "Estimate the rigid transform (rotation about z, shift) from memory A's map into "
            "memory B's, from image matches between them and a RANSAC fit of their poses (refined"
            " on their maps), or take the one given; with --apply, move A into B's map. Without "
            "--apply nothing is written."
        ),
    ),
    "eval": (
        "eval",
        ("Benchmarks (RAVEN-QA, NaVQA, FindingDory, your own questions), reports and studies."),
    ),
    "ros": (
        "ros",
        ("ROS 2: build the interfaces (setup), run the node (run)."),
    ),
}
