"""`memory.json`, the manifest of a memory folder: what built the memory and where its data lives.

A memory folder can come from anyone (a colleague, a download, a robot), so nothing in it is
trusted: the manifest is read as UTF-8 JSON of bounded size and every field is checked here,
before anything else touches the folder. A wrong field is one `InputError` naming the file and
the field; a manifest written by a newer ravenmem (a higher `format_version`) is refused rather
than half understood. Keys this version does not know are kept and written back unchanged.

Where the store lives (`store`) is confined too:
- `local`: the embedded store, inside the memory folder (the default);
- `milvus-lite:NAME.db`: a Milvus Lite file inside the memory folder (relative to it);
- `milvus://HOST:PORT` or `milvus://http(s)://HOST[:PORT]`: a Milvus server, written by `create`
  from the user's own `--store` argument and shown by `ravenmem info`. It is opened only when this
  user gave ravenmem that server: `create` records it in `~/.config/ravenmem/stores.json`
  (`$XDG_CONFIG_HOME`), and `RAVENMEM_TRUSTED_STORES` (comma-separated URIs) adds more, e.g. for
  a memory folder a colleague shares. A copied or edited manifest cannot choose a server.
Anything else (a path elsewhere, a relative path that escapes, another scheme) is refused, so a
manifest cannot make ravenmem create or open files outside its folder.
"""

from __future__ import annotations

import json
import math
import os
import re
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

from ..errors import InputError
from ..fsio import atomic_write, atomic_write_json
from .folder import MANIFEST

FORMAT_VERSION = 1  # the newest manifest format this code reads and writes
MAX_MANIFEST_BYTES = 64 << 20  # the ingest history grows ~0.5 KB per run: 64 MB is ~100k runs
LOCAL = "local"
# written only once known (span_seen: once `forget` resolved a relative time)
_UNSET_LEFT_OUT = ("frame_id", "map_id", "anchor", "span_seen")
LITE = "milvus-lite:"
_REMOTE = re.compile(r"(?:https?://)?[A-Za-z0-9_.\-]+:\d{1,5}/?|https?://[A-Za-z0-9_.\-]+/?")


@dataclass
class Manifest:
    """The typed content of `memory.json` (see the module docstring for what is checked)."""

    embedder: str
    dim: int
    store: str = LOCAL
    thumb_size: int = 0
    thumb_quality: int = 85
    ocr: bool = False
    created: float = 0.0
    ingests: list[dict[str, Any]] = field(default_factory=list)
    span_seen: list[float] | None = None  # [first, last] time this memory ever held (`forget`)
    format_version: int = FORMAT_VERSION
    # where the poses are (REP 105): their frame (`map`, or `odom` when there was no map frame)
    # and the map's identity; None in memories written before they were recorded (read as
    # `map` and `memory:<folder name>`). `anchor`: the transform `ravenmem align --apply` put
    # the poses through, and the map they came from (`ravenmem.memory.anchor`).
    frame_id: str | None = None
    map_id: str | None = None
    anchor: dict[str, Any] | None = None
    extra: dict[str, Any] = field(default_factory=dict)  # unknown keys, written back as they were

    def __post_init__(self) -> None:
        if not isinstance(self.embedder, str) or not self.embedder.strip():
            _bad("embedder", "a non-empty embedder name", self.embedder)
        _whole("format_version", self.format_version, 1)
        if self.format_version > FORMAT_VERSION:
            raise InputError(
                f"{MANIFEST}: format_version {self.format_version} was written by a newer ravenmem "
                f"(this one reads up to {FORMAT_VERSION}); upgrade ravenmem to open this memory"
            )
        _whole("dim", self.dim, 1, 1 << 20)
        _whole("thumb_size", self.thumb_size, 0, 1 << 16)
        _whole("thumb_quality", self.thumb_quality, 1, 100)
        if not isinstance(self.ocr, bool):
            _bad("ocr", "true or false", self.ocr)
        if isinstance(self.created, bool) or not isinstance(self.created, (int, float)):
            _bad("created", "a number (Unix seconds)", self.created)
        if not math.isfinite(self.created):
            _bad("created", "a finite number", self.created)
        if not isinstance(self.ingests, list) or not all(isinstance(r, dict) for r in self.ingests):
            _bad("ingests", "a list of objects", self.ingests)
        if self.span_seen is not None and not (
            isinstance(self.span_seen, list)
            and len(self.span_seen) == 2
            and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in self.span_seen)
            and all(math.isfinite(v) for v in self.span_seen)
            and self.span_seen[0] <= self.span_seen[1]
        ):
            _bad("span_seen", "[first, last] Unix seconds", self.span_seen)
        if not isinstance(self.store, str):
            _bad("store", "a string", self.store)
        store_kind(self.store)
        for name in ("frame_id", "map_id"):
            v = getattr(self, name)
            if v is not None and not is_name(v):
                _bad(name, "a name of 1 to 200 printable characters", v)
        if self.anchor is not None:
            check_anchor(self.anchor)

    # ------------------------------------------------------------------ JSON
    @classmethod
    def from_json(cls, data: Any) -> Manifest:
        """A manifest from parsed JSON; unknown keys go to `extra`."""
        if not isinstance(data, dict):
            raise InputError(f"{MANIFEST}: expected a JSON object, got {type(data).__name__}")
        known = {f.name for f in fields(cls)} - {"extra"}
        for key in ("embedder", "dim"):
            if key not in data:
                raise InputError(f"{MANIFEST}: field {key!r} is missing")
        args = {k: v for k, v in data.items() if k in known}
        extra = {k: v for k, v in data.items() if k not in known}
        return cls(**args, extra=extra)

    def to_json(self) -> dict[str, Any]:
        out = dict(self.extra)
        out.update({f.name: getattr(self, f.name) for f in fields(self) if f.name != "extra"})
        for key in _UNSET_LEFT_OUT:
            if out[key] is None:
                del out[key]
        return out

    @classmethod
    def load(cls, folder: Path) -> Manifest:
        """Read and check `folder/memory.json`; a one-line `InputError` for anything wrong."""
        path = folder / MANIFEST
        try:
            if path.stat().st_size > MAX_MANIFEST_BYTES:
                raise InputError(f"{path}: too large for a manifest (over {MAX_MANIFEST_BYTES >> 20} MB)")
            raw = path.read_bytes()
        except OSError as e:
            raise InputError(f"{path}: cannot be read ({e.strerror or e})") from None
        try:
            text = raw.decode("utf-8")
        except UnicodeDecodeError as e:
            raise InputError(f"{path}: not UTF-8 text (byte {e.start}); not a ravenmem manifest") from None
        try:
            data = json.loads(text)
        except (json.JSONDecodeError, RecursionError) as e:
            raise InputError(f"{path}: not valid JSON ({e})") from None
        try:
            return cls.from_json(data)
        except InputError as e:
            msg = str(e)
            prefix = f"{MANIFEST}: "
            raise InputError(f"{path}: {msg[len(prefix) :] if msg.startswith(prefix) else msg}") from None

    def save(self, folder: Path) -> None:
        """Write `folder/memory.json` crash-safely."""
        atomic_write(folder / MANIFEST, json.dumps(self.to_json(), indent=2, sort_keys=True) + "\n")

    # ------------------------------------------------------------------ the store
    def store_uri(self, folder: Path) -> str:
        """What `open_store` gets: the folder itself, a Lite file inside it, or the server URI."""
        kind = store_kind(self.store)
        if kind == "local":
            return str(folder)
        if kind == "remote":
            return self.store
        rel = self.store[len(LITE) :] if self.store.startswith(LITE) else self.store[len("milvus://") :]
        return "milvus://" + str(_inside(folder, rel, "store"))


def is_name(v: object) -> bool:
    """A frame or map name: 1 to 200 printable characters, no surrounding space."""
    return isinstance(v, str) and 0 < len(v) <= 200 and v == v.strip() and v.isprintable()


def check_anchor(a: object) -> None:
    """The manifest's `anchor`: {"transform": [x, y, z, yaw], "from": {"frame_id", "map_id"}, ...}."""
    if not isinstance(a, dict):
        _bad("anchor", "an object", a)
        return
    t = a.get("transform")
    ok = isinstance(t, list) and len(t) == 4
    ok = ok and all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in t)  # type: ignore[union-attr]
    if not ok:
        _bad("anchor.transform", "four finite numbers [x, y, z, yaw]", t)
    origin = a.get("from")
    if not isinstance(origin, dict) or not all(is_name(origin.get(k)) for k in ("frame_id", "map_id")):
        _bad("anchor.from", "the frame_id and map_id the poses came from", origin)


def store_kind(value: str) -> str:
    """`local`, `lite` or `remote` for a manifest's `store`; an `InputError` for anything else."""
    if value == LOCAL:
        return "local"
    if value.startswith(LITE):
        rel = value[len(LITE) :]
        if not rel or Path(rel).is_absolute() or ".." in Path(rel).parts or not rel.endswith(".db"):
            raise InputError(
                f"{MANIFEST}: store {value!r}: a Milvus Lite file must be a relative NAME.db inside the memory folder"
            )
        return "lite"
    if value.startswith("milvus://"):
        rest = value[len("milvus://") :]
        if _REMOTE.fullmatch(rest):
            return "remote"
        if rest.startswith("/") and rest.endswith(".db"):  # written by older versions: checked on open
            return "lite"
    raise InputError(
        f"{MANIFEST}: store {value!r} is not 'local', a Milvus Lite file inside the memory folder "
        "or milvus://HOST:PORT; refusing to open it"
    )


TRUST_ENV = "RAVENMEM_TRUSTED_STORES"


def trust_file() -> Path:
    """The user's list of Milvus servers given to `create` (`$XDG_CONFIG_HOME/ravenmem/stores.json`)."""
    base = os.environ.get("XDG_CONFIG_HOME") or str(Path.home() / ".config")
    return Path(base) / "ravenmem" / "stores.json"


def trusted_stores() -> set[str]:
    """Server URIs this user gave ravenmem: those `create` recorded, and `RAVENMEM_TRUSTED_STORES`."""
    out = {u.strip() for u in os.environ.get(TRUST_ENV, "").split(",") if u.strip()}
    try:
        data = json.loads(trust_file().read_text(encoding="utf-8"))
        out |= {u for u in data.get("trusted", []) if isinstance(u, str)}
    except (OSError, ValueError, AttributeError):
        pass  # no list yet (or an unreadable one): only the environment's
    return out


def trust_store(uri: str) -> None:
    """Record a server URI the user gave `create`, so that opening the memory later is allowed."""
    if uri in trusted_stores():
        return
    f = trust_file()
    try:
        data = json.loads(f.read_text(encoding="utf-8"))
        known = [u for u in data.get("trusted", []) if isinstance(u, str)]
    except (OSError, ValueError, AttributeError):
        known = []
    f.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_json(f, {"trusted": sorted({*known, uri})}, indent=2)


def check_trusted(uri: str) -> None:
    """Refuse a manifest's server URI that this user never gave ravenmem (one line)."""
    if uri not in trusted_stores():
        raise InputError(
            f"{MANIFEST}: store {uri!r} is a Milvus server this user never gave ravenmem (create "
            f"--store records it in {trust_file()}); a copied or edited memory.json cannot choose a "
            f"server. If you trust it: export {TRUST_ENV}={uri}"
        )


def store_for_create(value: str | None, folder: Path) -> str:
    """The manifest's `store` for the `--store` a user gave `create` (None: the embedded store).

    A Milvus Lite path must lie inside the new memory folder (it is kept relative to it, so the
    folder can move); a server URI is kept as written.
    """
    if value is None or value in (LOCAL, ""):
        return LOCAL
    if value.startswith("milvus://"):
        rest = value[len("milvus://") :]
        if _REMOTE.fullmatch(rest):
            return value
        if not rest.endswith(".db"):
            raise InputError(f"--store {value!r}: a Milvus Lite path must end in .db")
        target = Path(rest).expanduser().resolve()
        try:
            rel = target.relative_to(folder.expanduser().resolve())
        except ValueError:
            raise InputError(
                f"--store {value!r}: a Milvus Lite file must live inside the memory folder {folder}"
            ) from None
        return LITE + rel.as_posix()
    if value.startswith(LITE):
        store_kind(value)
        return value
    raise InputError(
        f"--store {value!r}: expected 'local', milvus:///PATH/INSIDE/THE/MEMORY/file.db or milvus://HOST:PORT"
    )


def confine(folder: Path, rel: str) -> Path | None:
    """`folder/rel` when it is a relative path that stays inside `folder` after symlinks are
    followed; None otherwise (absolute paths, `..`, links leading out)."""
    if not rel or "\x00" in rel:
        return None
    p = Path(rel)
    if p.is_absolute() or ".." in p.parts:
        return None
    try:
        root = folder.resolve()
        full = (folder / p).resolve()
        full.relative_to(root)
    except (OSError, ValueError, RuntimeError):
        return None
    return full


def _inside(folder: Path, rel: str, what: str) -> Path:
    p = Path(rel)
    if p.is_absolute():
        try:
            p.resolve().relative_to(folder.resolve())
        except ValueError:
            raise InputError(f"{folder / MANIFEST}: {what} {rel!r} lies outside the memory folder") from None
        return p.resolve()
    full = confine(folder, rel)
    if full is None:
        raise InputError(f"{folder / MANIFEST}: {what} {rel!r} lies outside the memory folder")
    return full


def _whole(name: str, v: Any, lo: int, hi: int | None = None) -> None:
    if isinstance(v, bool) or not isinstance(v, int) or v < lo or (hi is not None and v > hi):
        what = f"a whole number from {lo} to {hi}" if hi is not None else f"a whole number >= {lo}"
        _bad(name, what, v)


def _bad(name: str, expected: str, got: Any) -> None:
    shown = repr(got)
    if len(shown) > 60:
        shown = shown[:57] + "..."
    raise InputError(f"{MANIFEST}: field {name!r}: expected {expected}, got {shown}")
