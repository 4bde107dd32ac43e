"""The memory core: one folder on disk that holds what a robot saw, where and when.

`Memory` (`facade`) is built from one module per concern over `core`: the searches (`search`),
where a thing is now (`changes`, `places`, `views`), forgetting and consolidation (`lifelong`),
`info`; `create` and `open` make one (`create`). The folder's files are named in `folder`, and
every write goes through the writer handle (`writer`: the lock, the journals, the sidecars).
`protocol` is what the rest of ravenmem may rely on: `MemoryLike`, `check_k`.
"""

from __future__ import annotations

from .create import create, open
from .facade import Memory
from .protocol import MAX_K, MemoryLike, Near, TimeLike, check_k

__all__ = ["MAX_K", "Memory", "MemoryLike", "Near", "TimeLike", "check_k", "create", "open"]
