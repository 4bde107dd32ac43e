"""A memory that lives for months: forgetting, consolidation, and the sidecar tables they keep.

`Memory.forget` (`forget`) and `Memory.consolidate` (`consolidate`) are the entry points;
`ravenmem forget` and `ravenmem consolidate` the commands. What a consolidated memory stands
for lives in a sidecar table (`ravenmem.memory.groups`). Every write
goes through the memory's writer handle (`ravenmem.memory.writer`): the store, the thumbnail
journal (`ravenmem.memory.recovery`) and the groups table stay in step after a crash.
"""
