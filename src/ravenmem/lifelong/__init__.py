"""A memory that lives for months: forgetting, consolidation (and the sidecar tables they keep).

`Memory.forget` and `Memory.consolidate` are the entry points; `ravenmem forget` and
`ravenmem consolidate` the commands. This package sits on the memory floor: it uses the store
and the memory folder's crash-recovery journal (`ravenmem.recovery`), nothing above.
"""

from __future__ import annotations

from .consolidate import ConsolidateReport
from .forget import ForgetReport

__all__ = ["ConsolidateReport", "ForgetReport"]
