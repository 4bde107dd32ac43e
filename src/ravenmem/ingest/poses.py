"""Pose tracks: read a timestamped trajectory file and look up the pose at any frame time.

Sources get frames and poses on separate clocks/rates (30 Hz video, 100 Hz motion capture,
50 Hz odometry), so every source goes through one `PoseTrack`: linear interpolation for
position, slerp for full orientations, shortest-arc interpolation for yaw-only tracks, or the
nearest sample within a maximum gap. A frame with no pose is never guessed: the lookup says why
(`SKIP_OUTSIDE`, `SKIP_GAP`) and the source counts it.

File layouts (one row per sample, `#` starts a comment, blank lines ignored):

* CSV (comma-separated): `t,x,y,z`, `t,x,y,z,yaw` or `t,x,y,z,qx,qy,qz,qw`, with an optional
  header row. With a header, columns are found by name in any order (see `_ALIASES`), `z` is
  optional and a `file` column may name an image (used by the folder source).
* TUM (space-separated): `t tx ty tz qx qy qz qw`, the TUM RGB-D `groundtruth.txt` layout.
"""

from __future__ import annotations

import io
import math
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike

from ..errors import InputError
from ..fsio import read_text
from ..types import MAX_ANGLE, MAX_COORD, RANGES, T_MAX, T_MIN, Pose

MAX_POSES = 512 << 20  # bytes of a pose file: 6 million rows (16 hours at 100 Hz)
SKIP_OUTSIDE = "outside pose track"
SKIP_GAP = "pose gap too large"

MatchMode = Literal["interpolate", "nearest"]

_ALIASES: dict[str, tuple[str, ...]] = {
    "t": ("t", "time", "timestamp", "stamp", "t_s", "time_s", "sec", "secs", "seconds"),
    "x": ("x", "tx", "pos_x", "position_x", "px"),
    "y": ("y", "ty", "pos_y", "position_y", "py"),
    "z": ("z", "tz", "pos_z", "position_z", "pz"),
    "yaw": ("yaw", "heading", "theta", "yaw_rad"),
    "qx": ("qx", "q_x", "quat_x", "orientation_x"),
    "qy": ("qy", "q_y", "quat_y", "orientation_y"),
    "qz": ("qz", "q_z", "quat_z", "orientation_z"),
    "qw": ("qw", "q_w", "quat_w", "orientation_w"),
    "file": ("file", "filename", "image", "image_file", "path"),
}
_BY_COUNT: dict[int, tuple[str, ...]] = {
    4: ("t", "x", "y", "z"),
    5: ("t", "x", "y", "z", "yaw"),
    8: ("t", "x", "y", "z", "qx", "qy", "qz", "qw"),
}
_QUAT = ("qx", "qy", "qz", "qw")


def _is_number(s: str) -> bool:
    try:
        float(s)
    except ValueError:
        return False
    return True


def _wrap(a: np.ndarray) -> np.ndarray:
    """Wrap angles to [-pi, pi)."""
    return (a + np.pi) % (2.0 * np.pi) - np.pi


def yaw_of(q: np.ndarray) -> np.ndarray:
    """Rotation about +z of (N, 4) x, y, z, w quaternions (the same rule as Pose.from_quaternion)."""
    x, y, z, w = q[:, 0], q[:, 1], q[:, 2], q[:, 3]
    return np.arctan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


def slerp(q0: np.ndarray, q1: np.ndarray, a: np.ndarray) -> np.ndarray:
    """Row-wise spherical linear interpolation of unit quaternions along the shorter arc.

    Written out (rather than scipy's Slerp) because sources look up one frame at a time and
    scipy's per-call overhead is ~0.5 ms; tests check it against scipy on random rotations.
    """
    dot = np.einsum("ij,ij->i", q0, q1)
    q1 = np.where(dot[:, None] < 0, -q1, q1)
    dot = np.clip(np.abs(dot), 0.0, 1.0)
    theta = np.arccos(dot)
    s = np.sin(theta)
    near = s < 1e-9  # (almost) the same rotation: linear blend is exact enough
    s_safe = np.where(near, 1.0, s)
    w0 = np.where(near, 1.0 - a, np.sin((1.0 - a) * theta) / s_safe)
    w1 = np.where(near, a, np.sin(a * theta) / s_safe)
    q = w0[:, None] * q0 + w1[:, None] * q1
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def _slerp1(q0: list[float], q1: list[float], a: float) -> list[float]:
    """`slerp` for one pair of quaternions, in plain floats."""
    dot = sum(u * v for u, v in zip(q0, q1, strict=True))
    if dot < 0:
        q1, dot = [-v for v in q1], -dot
    theta = math.acos(min(dot, 1.0))
    s = math.sin(theta)
    if s < 1e-9:
        w0, w1 = 1.0 - a, a
    else:
        w0, w1 = math.sin((1.0 - a) * theta) / s, math.sin(a * theta) / s
    return [w0 * u + w1 * v for u, v in zip(q0, q1, strict=True)]


@dataclass
class PoseTable:
    """The rows of a pose file as arrays, with the source line of every row for error messages."""

    path: str
    lines: np.ndarray  # 1-based line number of each row
    t: np.ndarray | None
    xyz: np.ndarray
    yaw: np.ndarray | None
    quat: np.ndarray | None  # (N, 4) x, y, z, w, normalised
    files: list[str] | None

    def __len__(self) -> int:
        return len(self.xyz)


def _columns_from_header(fields: list[str], where: str) -> list[str | None]:
    lookup = {alias: key for key, names in _ALIASES.items() for alias in names}
    cols: list[str | None] = []
    for f in fields:
        key = lookup.get(f.strip().lower())
        if key is not None and key in cols:
            raise InputError(f"{where}: column {key!r} appears twice in the header")
        cols.append(key)
    found = {c for c in cols if c}
    missing = [k for k in ("x", "y") if k not in found]
    if "t" not in found and "file" not in found:
        missing.insert(0, "t")
    if missing:
        raise InputError(
            f"{where}: header {','.join(fields)!r} has no column for {', '.join(missing)} "
            f"(known names: t/time/timestamp, x, y, z, yaw, qx..qw, file)"
        )
    q = [k for k in _QUAT if k in found]
    if q and len(q) != 4:
        raise InputError(f"{where}: header has {', '.join(q)} but a quaternion needs all of qx, qy, qz, qw")
    return cols


def _split(line: str) -> list[str]:
    return [f.strip() for f in line.split(",")] if "," in line else line.split()


def read_pose_table(path: str | Path) -> PoseTable:
    """Parse a CSV or TUM pose file; any bad value raises InputError naming file, line and column.

    Well-formed numeric files take numpy's C parser (an hour at 100 Hz in about a second); if it
    refuses, a line-by-line pass finds and names the first bad line and field.
    """
    p = Path(path)
    text = read_text(p, MAX_POSES, "pose file", errors="replace")
    lines = text.splitlines()
    first = next((n for n, raw in enumerate(lines, 1) if raw.split("#", 1)[0].strip()), None)
    if first is None:
        raise InputError(f"{p}: no pose rows found")
    line = lines[first - 1].split("#", 1)[0].strip()
    fields = _split(line)
    skip = first - 1
    if not any(_is_number(f) for f in fields):
        cols = _columns_from_header(fields, f"{p} line {first}")
        skip = first
    elif len(fields) in _BY_COUNT:
        cols = list(_BY_COUNT[len(fields)])
    else:
        raise InputError(
            f"{p} line {first}: {len(fields)} columns without a header; expected 4 (t,x,y,z), "
            f"5 (t,x,y,z,yaw) or 8 (t,x,y,z,qx,qy,qz,qw), or add a header row"
        )
    nums = np.asarray(
        [n for n, raw in enumerate(lines[skip:], skip + 1) if raw.split("#", 1)[0].strip()], dtype=np.int64
    )
    if not len(nums):
        raise InputError(f"{p}: no pose rows found")
    num_idx = [i for i, c in enumerate(cols) if c is not None and c != "file"]
    names = [str(cols[i]) for i in num_idx]
    data = None
    if "file" not in cols:
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                arr = np.loadtxt(
                    io.StringIO(text),
                    comments="#",
                    delimiter="," if "," in line else None,
                    skiprows=skip,
                    usecols=None if len(num_idx) == len(cols) else num_idx,
                    ndmin=2,
                    dtype=np.float64,
                )
            if arr.shape == (len(nums), len(num_idx)) and np.isfinite(arr).all():
                data = arr
        except ValueError:
            data = None
    files = None
    if data is None:
        data, files = _parse_slowly(p, lines, nums, cols, num_idx)
    return _table(p, nums, names, data, files)


def _parse_slowly(
    p: Path, lines: list[str], nums: np.ndarray, cols: list[str | None], num_idx: list[int]
) -> tuple[np.ndarray, list[str] | None]:
    """Line-by-line parse that names the first bad line and field."""
    data = np.empty((len(nums), len(num_idx)))
    files: list[str] | None = [] if "file" in cols else None
    for r, n in enumerate(nums.tolist()):
        fields = _split(lines[n - 1].split("#", 1)[0].strip())
        if len(fields) != len(cols):
            raise InputError(f"{p} line {n}: expected {len(cols)} columns, found {len(fields)}")
        for j, i in enumerate(num_idx):
            try:
                v = float(fields[i])
            except ValueError:
                raise InputError(f"{p} line {n}, column {cols[i]!r}: not a number: {fields[i]!r}") from None
            if not math.isfinite(v):
                raise InputError(f"{p} line {n}, column {cols[i]!r}: not a finite number: {fields[i]!r}")
            data[r, j] = v
        if files is not None:
            files.append(fields[cols.index("file")])
    return data, files


def _table(
    p: Path, lines: np.ndarray, names: list[str], data: np.ndarray, files: list[str] | None
) -> PoseTable:
    col = {name: data[:, j] for j, name in enumerate(names)}
    _check_ranges(p, lines, col)
    zeros = np.zeros(len(data))
    xyz = np.stack([col["x"], col["y"], col.get("z", zeros)], axis=1)
    quat = None
    if "qx" in col:
        quat = np.stack([col[k] for k in _QUAT], axis=1)
        norm = np.linalg.norm(quat, axis=1)
        bad = np.flatnonzero(norm < 1e-9)
        if bad.size:
            raise InputError(f"{p} line {lines[bad[0]]}, columns qx..qw: quaternion has zero norm")
        quat = quat / norm[:, None]
    return PoseTable(str(p), lines, col.get("t"), xyz, col.get("yaw"), quat, files)


def _check_ranges(p: Path, lines: np.ndarray, col: dict[str, np.ndarray]) -> None:
    """Times, positions and headings within the ranges a memory stores (`ravenmem.types`),
    naming the first line outside them."""
    limits = {"t": (T_MIN, T_MAX, RANGES["t"]), "yaw": (-MAX_ANGLE, MAX_ANGLE, RANGES["angle"])}
    limits |= {c: (-MAX_COORD, MAX_COORD, RANGES["coordinate"]) for c in "xyz"}
    for name, (lo, hi, what) in limits.items():
        if name not in col:
            continue
        bad = np.flatnonzero((col[name] < lo) | (col[name] > hi))
        if bad.size:
            raise InputError(
                f"{p} line {lines[bad[0]]}, column {name!r}: {col[name][bad[0]]!r} is out of range ({what})"
            )


class PoseTrack:
    """A time-sorted trajectory with vectorised interpolation and nearest-sample lookup.

    Rotation is whatever the data has: full quaternions (slerp), yaw only (interpolated on the
    circle) or none (yaw 0, quat None: a position-only track says nothing about heading).
    """

    def __init__(
        self,
        t: ArrayLike,
        xyz: ArrayLike,
        quat: ArrayLike | None = None,
        yaw: ArrayLike | None = None,
        name: str = "pose track",
    ) -> None:
        self.t = np.asarray(t, dtype=np.float64).reshape(-1)
        self.xyz = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
        self.name = name
        n = len(self.t)
        if n == 0:
            raise InputError(f"{name}: pose track is empty")
        if len(self.xyz) != n:
            raise ValueError("t and xyz lengths differ")
        if np.any(np.diff(self.t) <= 0):
            raise ValueError(f"{name}: timestamps must be strictly increasing")
        self.quat: np.ndarray | None = None
        # what orientation the data carries: "quat", "yaw" or "none"
        self.rotation = "quat" if quat is not None else ("yaw" if yaw is not None else "none")
        if quat is not None:
            q = np.asarray(quat, dtype=np.float64).reshape(-1, 4)
            self.quat = q / np.linalg.norm(q, axis=1, keepdims=True)
            self.yaw = yaw_of(self.quat)
        elif yaw is not None:
            self.yaw = _wrap(np.asarray(yaw, dtype=np.float64).reshape(-1))
        else:
            self.yaw = np.zeros(n)
        self._yaw_unwrapped = np.unwrap(self.yaw)
        self._t0, self._t1 = float(self.t[0]), float(self.t[-1])

    @classmethod
    def from_table(cls, table: PoseTable, sort: bool = False) -> PoseTrack:
        """Build a track from a parsed file; time must increase unless `sort` (which also drops repeats)."""
        if table.t is None:
            raise InputError(f"{table.path}: pose file has no time column (t/time/timestamp)")
        t = table.t
        if sort:
            return cls.from_samples(t, table.xyz, table.quat, table.yaw, name=table.path)
        bad = np.flatnonzero(np.diff(t) <= 0)
        if bad.size:
            i = bad[0] + 1
            raise InputError(
                f"{table.path} line {table.lines[i]}, column 't': timestamp {float(t[i])!r} is not after "
                f"{float(t[i - 1])!r} on line {table.lines[i - 1]} (timestamps must increase; pass sort=True to sort)"
            )
        return cls(t, table.xyz, table.quat, table.yaw, name=table.path)

    @classmethod
    def from_samples(
        cls,
        t: ArrayLike,
        xyz: ArrayLike,
        quat: ArrayLike | None = None,
        yaw: ArrayLike | None = None,
        name: str = "pose track",
    ) -> PoseTrack:
        """Build from samples in any order (e.g. bag messages); repeated times keep the last sample."""
        ta = np.asarray(t, dtype=np.float64).reshape(-1)
        order = np.argsort(ta, kind="stable")
        order = order[np.r_[np.diff(ta[order]) > 0, True]] if len(order) else order
        return cls(
            ta[order],
            np.asarray(xyz, dtype=np.float64).reshape(-1, 3)[order],
            None if quat is None else np.asarray(quat, dtype=np.float64).reshape(-1, 4)[order],
            None if yaw is None else np.asarray(yaw, dtype=np.float64).reshape(-1)[order],
            name=name,
        )

    def __len__(self) -> int:
        return len(self.t)

    @property
    def span(self) -> tuple[float, float]:
        return float(self.t[0]), float(self.t[-1])

    def pose_at(self, i: int) -> Pose:
        """The i-th sample as a Pose."""
        x, y, z = (float(v) for v in self.xyz[i])
        if self.quat is not None:
            return Pose.from_quaternion(x, y, z, *(float(v) for v in self.quat[i]))
        return Pose(x, y, z, float(self.yaw[i]))

    def interpolate_many(
        self, ts: ArrayLike, max_gap: float | None = None
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]:
        """Vectorised interpolation: (valid mask, xyz (M,3), yaw (M,), quat (M,4) or None).

        Invalid rows (outside the span, or between samples more than `max_gap` s apart) hold NaN.
        """
        ts = np.asarray(ts, dtype=np.float64).reshape(-1)
        m = len(ts)
        valid = (ts >= self.t[0]) & (ts <= self.t[-1])
        if len(self.t) >= 2 and max_gap is not None:
            hi = np.clip(np.searchsorted(self.t, ts, side="right"), 1, len(self.t) - 1)
            lo_t, hi_t = self.t[hi - 1], self.t[hi]
            valid &= (lo_t == ts) | (hi_t == ts) | (hi_t - lo_t <= max_gap)
        xyz = np.full((m, 3), np.nan)
        yaw = np.full(m, np.nan)
        quat = None if self.quat is None else np.full((m, 4), np.nan)
        tv = ts[valid]
        if tv.size == 0:
            return valid, xyz, yaw, quat
        if len(self.t) == 1:
            xyz[valid] = self.xyz[0]
            yaw[valid] = self.yaw[0]
            if quat is not None and self.quat is not None:
                quat[valid] = self.quat[0]
            return valid, xyz, yaw, quat
        hi = np.clip(np.searchsorted(self.t, tv, side="right"), 1, len(self.t) - 1)
        lo = hi - 1
        a = np.clip((tv - self.t[lo]) / (self.t[hi] - self.t[lo]), 0.0, 1.0)
        xyz[valid] = self.xyz[lo] + a[:, None] * (self.xyz[hi] - self.xyz[lo])
        if quat is not None and self.quat is not None:
            q = slerp(self.quat[lo], self.quat[hi], a)
            quat[valid] = q
            yaw[valid] = yaw_of(q)
        else:
            yu = self._yaw_unwrapped
            yaw[valid] = _wrap(yu[lo] + a * (yu[hi] - yu[lo]))
        return valid, xyz, yaw, quat

    def interpolate(self, t: float, max_gap: float | None = None) -> Pose | None:
        """Pose at time t, or None outside the track (or inside a gap wider than max_gap).

        Same result as `interpolate_many`, in plain floats: sources look up one frame at a time
        and small-array numpy calls would cost more than the arithmetic.
        """
        t = float(t)
        n = len(self.t)
        if not self._t0 <= t <= self._t1:
            return None
        if n == 1:
            return self.pose_at(0)
        hi = min(max(int(self.t.searchsorted(t, side="right")), 1), n - 1)
        lo = hi - 1
        ta, tb = float(self.t[lo]), float(self.t[hi])
        if max_gap is not None and tb - ta > max_gap and t != ta and t != tb:
            return None
        a = min(max((t - ta) / (tb - ta), 0.0), 1.0)
        p0, p1 = self.xyz[lo].tolist(), self.xyz[hi].tolist()
        x, y, z = (u + a * (v - u) for u, v in zip(p0, p1, strict=True))
        if self.quat is not None:
            return Pose.from_quaternion(x, y, z, *_slerp1(self.quat[lo].tolist(), self.quat[hi].tolist(), a))
        ya, yb = float(self._yaw_unwrapped[lo]), float(self._yaw_unwrapped[hi])
        return Pose(x, y, z, (ya + a * (yb - ya) + math.pi) % (2.0 * math.pi) - math.pi)

    def nearest_index_many(self, ts: ArrayLike, max_gap: float) -> np.ndarray:
        """Index of the sample nearest each time, -1 where the nearest is more than max_gap away."""
        ts = np.asarray(ts, dtype=np.float64).reshape(-1)
        hi = np.clip(np.searchsorted(self.t, ts), 0, len(self.t) - 1)
        lo = np.clip(hi - 1, 0, len(self.t) - 1)
        pick = np.where(np.abs(self.t[lo] - ts) <= np.abs(self.t[hi] - ts), lo, hi)
        return np.where(np.abs(self.t[pick] - ts) <= max_gap, pick, -1)

    def nearest(self, t: float, max_gap: float) -> Pose | None:
        """The sample nearest in time, or None when it is more than max_gap seconds away."""
        i = int(self.nearest_index_many([t], max_gap)[0])
        return None if i < 0 else self.pose_at(i)

    def match(self, t: float, mode: MatchMode = "interpolate", max_gap: float | None = None) -> Pose | str:
        """Pose for a frame at time t, or the skip reason (`SKIP_OUTSIDE` / `SKIP_GAP`) when none."""
        if mode == "nearest":
            if max_gap is None:
                raise ValueError("nearest matching needs max_gap")
            pose = self.nearest(t, max_gap)
        elif mode == "interpolate":
            pose = self.interpolate(t, max_gap)
        else:
            raise InputError(f"unknown pose matching {mode!r}; choose interpolate or nearest")
        if pose is not None:
            return pose
        lo = self.t[0] - (max_gap if mode == "nearest" and max_gap else 0.0)
        hi = self.t[-1] + (max_gap if mode == "nearest" and max_gap else 0.0)
        return SKIP_OUTSIDE if (t < lo or t > hi) else SKIP_GAP


def load_pose_track(path: str | Path, sort: bool = False) -> PoseTrack:
    """Read a CSV/TUM pose file into a PoseTrack (see the module docstring for layouts)."""
    return PoseTrack.from_table(read_pose_table(path), sort=sort)


def check_match_mode(mode: str) -> MatchMode:
    """Validate a user-given pose matching mode."""
    if mode not in ("interpolate", "nearest"):
        raise InputError(f"unknown pose matching {mode!r}; choose interpolate or nearest")
    return mode  # type: ignore[return-value]
