"""A tiny name -> factory registry, one per swappable axis (embedders, stores, sources, ...).

Backends register themselves with a decorator; configs name them with a string such as
`offline`, `open_clip:ViT-B-32/laion2b_s34b_b79k` or `hf:/path/to/siglip`. The part after the
first ':' is handed to the factory as `spec` so each backend parses its own options.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Generic, TypeVar

from .errors import InputError

T = TypeVar("T")


class Registry(Generic[T]):
    def __init__(self, kind: str) -> None:
        self.kind = kind
        self._factories: dict[str, Callable[..., T]] = {}

    def register(self, name: str) -> Callable[[Callable[..., T]], Callable[..., T]]:
        def deco(factory: Callable[..., T]) -> Callable[..., T]:
            self._factories[name] = factory
            return factory

        return deco

    def names(self) -> list[str]:
        return sorted(self._factories)

    def create(self, spec: str, **kwargs: object) -> T:
        """Create a backend from `name` or `name:options`."""
        name, _, rest = spec.partition(":")
        if name not in self._factories:
            raise InputError(f"unknown {self.kind} {name!r}; choose one of: {', '.join(self.names())}")
        return self._factories[name](rest, **kwargs)
