"""A tiny name -> factory registry, one per swappable axis (embedders, stores, sources, ...).

Backends register themselves with a decorator; configs name them with a string such as
`offline`, `open_clip:ViT-B-32/laion2b_s34b_b79k` or `hf:/path/to/siglip`. The part after the
first ':' is handed to the factory as `spec` so each backend parses its own options.

Every registry loads its backends the same lazy way, so that naming one backend never imports
the others (or their heavy dependencies):

- built-in backends are listed as `name -> module`; the module is imported the first time the
  name is asked for, and registers its factory with `@REGISTRY.register(name)`;
- third-party packages add backends through the entry-point group `ravenmem.<axis>` (for
  example `[project.entry-points."ravenmem.embedders"] mine = "my_pkg.emb:make"`); the entry
  point is loaded the first time its name is asked for and its object is the factory.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Mapping
from importlib import metadata
from typing import Generic, TypeVar

from .errors import InputError

T = TypeVar("T")


class Registry(Generic[T]):
    """Factories by name for one axis; see the module docstring for how backends load."""

    def __init__(
        self, kind: str, group: str | None = None, builtins: Mapping[str, str] | None = None
    ) -> None:
        self.kind = kind
        self.group = group
        self._builtins = dict(builtins or {})
        self._factories: dict[str, Callable[..., T]] = {}

    def register(self, name: str) -> Callable[[Callable[..., T]], Callable[..., T]]:
        def deco(factory: Callable[..., T]) -> Callable[..., T]:
            self._factories[name] = factory
            return factory

        return deco

    def _entry_points(self) -> dict[str, metadata.EntryPoint]:
        if not self.group:
            return {}
        return {ep.name: ep for ep in metadata.entry_points(group=self.group)}

    def names(self) -> list[str]:
        """Every name this registry can create, without importing any backend."""
        return sorted(set(self._factories) | set(self._builtins) | set(self._entry_points()))

    def get(self, name: str) -> Callable[..., T]:
        """The factory for `name`, importing its module or entry point on first use."""
        if name not in self._factories and name in self._builtins:
            importlib.import_module(self._builtins[name])
        if name not in self._factories:
            ep = self._entry_points().get(name)
            if ep is not None:
                self._factories[name] = ep.load()
        if name not in self._factories:
            raise InputError(f"unknown {self.kind} {name!r}; choose one of: {', '.join(self.names())}")
        return self._factories[name]

    def create(self, spec: str, **kwargs: object) -> T:
        """Create a backend from `name` or `name:options`."""
        name, _, rest = spec.partition(":")
        return self.get(name)(rest, **kwargs)
