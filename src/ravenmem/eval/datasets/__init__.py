"""Benchmark loaders: `NAME:PATH` -> a list of `Episode`s (see each module for its exact layout).

raven-qa:PATH      RAVEN-QA (and our simulated episodes exported in its layout)
navqa:PATH         NaVQA over your CODa conversion
findingdory:PATH   FindingDory validation split
tum: / video: / folder: / rosbag: / memory:PATH  with --queries QUESTIONS.json (our format)
queries:QUESTIONS.json                           a questions file that names its own source
"""

from __future__ import annotations

from typing import Any

from ...errors import InputError
from ...registry import Registry
from ..types import Episode

# recording formats a questions file can be paired with (`generic`); `queries:` names its own
SOURCE_FORMATS = ("tum", "video", "folder", "rosbag", "bag", "mcap", "memory")
_HERE = "ravenmem.eval.datasets."
# built-ins load like every registry's: a module is imported when one of its names is asked for
DATASETS: Registry[list[Episode]] = Registry(
    "dataset",
    "ravenmem.datasets",
    {
        "raven-qa": _HERE + "ravenqa",
        "ravenqa": _HERE + "ravenqa",
        "navqa": _HERE + "navqa",
        "findingdory": _HERE + "findingdory",
        **dict.fromkeys((*SOURCE_FORMATS, "queries"), _HERE + "generic"),
    },
)


def load_dataset(spec: str, queries: str | None = None, **opts: Any) -> list[Episode]:
    """Load `NAME:PATH`; `queries` is our questions.json for recording formats (tum:, video:, ...)."""
    name, sep, path = spec.partition(":")
    if not sep or not path:
        raise InputError(f"dataset {spec!r}: expected NAME:PATH, NAME one of {', '.join(DATASETS.names())}")
    if queries is not None and name in ("raven-qa", "ravenqa", "navqa", "findingdory"):
        raise InputError(f"--queries is for recording datasets (tum:, video:, ...), not {name}:")
    kwargs = dict(opts)
    if queries is not None:
        kwargs["queries"] = queries
    episodes = DATASETS.create(spec, **kwargs)
    if not episodes or not any(e.questions for e in episodes):
        raise InputError(f"dataset {spec!r} holds no questions")
    return episodes


__all__ = ["DATASETS", "load_dataset"]
