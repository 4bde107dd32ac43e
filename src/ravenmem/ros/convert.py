"""rclpy messages <-> plain dicts, the shape `ros.services` speaks (`rosidl_runtime_py`, which
does this in a ROS 2 distribution, is not on PyPI). Message classes are imported directly."""

from __future__ import annotations

import array
import importlib
from typing import Any

import numpy as np

_PRIMITIVE_SEQ = ("sequence<", "uint8[", "float64[", "float32[", "int8[", "int16[", "int32[", "int64[")


def message_class(type_name: str) -> Any:
    """`geometry_msgs/PoseStamped` or `geometry_msgs/msg/PoseStamped` -> the class."""
    parts = type_name.split("/")
    pkg, name = parts[0], parts[-1]
    return getattr(importlib.import_module(f"{pkg}.msg"), name)


def to_dict(msg: Any) -> Any:
    """A message as nested dicts (the shape `ros.msgs.to_message` takes); byte arrays as bytes."""
    if not hasattr(msg, "get_fields_and_field_types"):
        if isinstance(msg, (array.array, bytes, bytearray, memoryview)):
            return bytes(msg) if _bytes_like(msg) else list(msg)
        if isinstance(msg, (list, tuple)):
            return [to_dict(v) for v in msg]
        if isinstance(msg, np.ndarray):
            return msg.tolist()
        return msg
    return {name: to_dict(getattr(msg, name)) for name in msg.get_fields_and_field_types()}


def _bytes_like(v: Any) -> bool:
    return not isinstance(v, array.array) or v.typecode in ("B", "b")


def fill(msg: Any, data: dict[str, Any]) -> Any:
    """Set `msg`'s fields from `data` (missing keys keep their defaults); returns msg."""
    types = msg.get_fields_and_field_types()
    for name, value in data.items():
        if name not in types:
            raise KeyError(f"{type(msg).__name__} has no field {name!r}")
        kind = types[name]
        current = getattr(msg, name)
        if hasattr(current, "get_fields_and_field_types"):
            fill(current, value or {})
        elif kind.startswith("sequence<") and "/" in kind:
            cls = message_class(kind[len("sequence<") : -1].split(",")[0])
            setattr(msg, name, [fill(cls(), v) for v in value])
        elif kind.startswith(_PRIMITIVE_SEQ):
            setattr(msg, name, list(value) if not isinstance(value, (bytes, bytearray)) else value)
        else:
            setattr(msg, name, value)
    return msg
