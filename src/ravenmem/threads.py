"""Threads on a shared computer: pools that sleep when idle, background work below searches.

A robot's computer is shared (SLAM, the planner, perception), and a served memory does two
kinds of work: answering searches, which someone waits for, and storing frames and reading
their text, which can lag a little.

- `share_cores()`: the OpenMP thread pools of torch and FAISS spin (busy-wait) after each
  parallel step by default, which on a busy computer takes the cores from everything else and
  from the pool's own next step. The `ravenmem` command (and the ROS 2 node) set
  `OMP_WAIT_POLICY=PASSIVE` before those libraries load, unless the user set it.
- `lower_priority(by)`: the threads that do the background work lower their own priority: on
  Linux a thread has its own nice value, and the threads it starts afterwards (the OCR engine's
  pool, torch's intra-op team of that thread) inherit it, so the scheduler runs the searches
  first whenever both are ready, and the background work still gets its share. Raising it back
  needs privileges, so it is only lowered.
"""

from __future__ import annotations

import contextlib
import os
import threading

WRITER_NICE = 2  # the live writer (embedding, storing): a little below the searches
TEXT_NICE = 5  # reading text after the write: below the writer, whose answers a robot waits for


def share_cores() -> None:
    """Let OpenMP pools sleep while they wait (see the module docstring); must run before torch
    or FAISS is imported, and leaves a value the user set alone."""
    os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")


def lower_priority(by: int) -> None:
    """Lower the calling thread's priority by `by` nice steps (nothing where not supported)."""
    if by <= 0:
        return
    with contextlib.suppress(AttributeError, OSError):  # not Linux, or not allowed: as it is
        tid = threading.get_native_id()
        os.setpriority(os.PRIO_PROCESS, tid, min(19, os.getpriority(os.PRIO_PROCESS, tid) + by))
