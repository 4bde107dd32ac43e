"""ROS 2 Nav2 interop: map_server maps (YAML + PGM). Goals are `ravenmem.nav.goals` plans,
sent as `geometry_msgs/PoseStamped` (`nav.goals.pose_stamped`) or a NavigateToPose action
(`ravenmem.ros.action`).

map_server conventions (nav2_map_server, `map_saver_cli` defaults), followed exactly:

- YAML keys `image` (path relative to the YAML file), `mode` (`trinary` here), `resolution`
  (metres per pixel), `origin` [x, y, yaw] (the map-frame pose of the image's lower-left
  pixel corner), `negate` (0), `occupied_thresh` (0.65), `free_thresh` (0.196: the value
  map_saver has always written; with 0.25 map_server's own unknown grey, 205, would load as
  free, since (255 - 205) / 255 = 0.196).
- Pixel value v gives occupancy p = (255 - v) / 255 (p = v / 255 when negate is 1);
  p > occupied_thresh is occupied, p < free_thresh is free, anything between is unknown.
  Saved maps use 0 = occupied, 254 = free, 205 = unknown.
- Image row 0 is the TOP of the map (largest y); our grid's row 0 is the smallest y, so rows
  are flipped on the way out and back.

Only origins with yaw 0 are read (map_server itself ignores the yaw in most tools); other
modes than trinary/scale are refused with a one-line reason.
"""

from __future__ import annotations

import io
import math
from pathlib import Path
from typing import Any

import numpy as np
from PIL import Image

from ..errors import InputError
from ..fsio import MAX_CONFIG, atomic_write, read_text
from ..nav.frame import MapFrame
from ..nav.grid import MapConfig, OccupancyGrid, read_map_image
from ..types import check_coord

FREE, OCCUPIED, UNKNOWN = 254, 0, 205
OCCUPIED_THRESH, FREE_THRESH = 0.65, 0.196


def export_map_server(grid: OccupancyGrid, yaml_path: str | Path) -> tuple[Path, Path]:
    """Write `NAME.yaml` and `NAME.pgm` (trinary, unknown kept unknown). Obstacles are not
    inflated: Nav2's costmap inflates them with the robot's own footprint."""
    yaml_path = Path(yaml_path)
    if yaml_path.suffix.lower() not in (".yaml", ".yml"):
        raise InputError(f"{yaml_path}: a map_server map is a .yaml file (its image goes next to it)")
    if grid.shape[0] == 0 or grid.shape[1] == 0:
        raise InputError("the map is empty: nothing to export")
    pgm_path = yaml_path.with_suffix(".pgm")
    img = np.full(grid.shape, UNKNOWN, np.uint8)
    img[grid.free] = FREE
    img[grid.occupied] = OCCUPIED
    buf = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(img[::-1])).save(buf, format="PPM")  # mode L -> binary P5
    atomic_write(pgm_path, buf.getvalue())
    ox, oy = grid.origin
    text = (
        f"image: {pgm_path.name}\n"
        "mode: trinary\n"
        f"resolution: {grid.resolution!r}\n"
        f"origin: [{ox!r}, {oy!r}, 0.0]\n"
        "negate: 0\n"
        f"occupied_thresh: {OCCUPIED_THRESH}\n"
        f"free_thresh: {FREE_THRESH}\n"
    )
    atomic_write(yaml_path, text)
    return yaml_path, pgm_path


def _num(meta: dict[str, Any], key: str, where: Path) -> float:
    try:
        v = float(meta[key])
    except KeyError:
        raise InputError(
            f"{where}: no '{key}' (a map_server YAML needs image, resolution and origin)"
        ) from None
    except (TypeError, ValueError):
        raise InputError(f"{where}, field '{key}': not a number: {meta[key]!r}") from None
    if not math.isfinite(v):
        raise InputError(f"{where}, field '{key}': not finite")
    return v


def import_map_server(yaml_path: str | Path) -> OccupancyGrid:
    """Read a map_server map into a grid (map frame = the memory's world frame, z up)."""
    from ruamel.yaml import YAML, YAMLError

    yaml_path = Path(yaml_path)
    if not yaml_path.is_file():
        raise InputError(f"{yaml_path}: no such map YAML")
    try:
        meta = YAML(typ="safe").load(read_text(yaml_path, MAX_CONFIG, "map YAML"))
    except (YAMLError, UnicodeDecodeError) as e:
        raise InputError(f"{yaml_path}: not valid YAML ({str(e).splitlines()[0]})") from None
    if not isinstance(meta, dict):
        raise InputError(f"{yaml_path}: expected a mapping of map_server keys")
    res = _num(meta, "resolution", yaml_path)
    if not 1e-3 <= res <= 10:  # a millimetre to 10 m a cell: anything else makes no map
        raise InputError(f"{yaml_path}, field 'resolution': must be from 0.001 to 10 m, got {res}")
    origin = meta.get("origin")
    if not isinstance(origin, (list, tuple)) or len(origin) != 3:
        raise InputError(f"{yaml_path}, field 'origin': expected [x, y, yaw], got {origin!r}")
    ox, oy, oyaw = (_num({"origin": v}, "origin", yaml_path) for v in origin)
    for corner in (ox, oy):
        check_coord(corner, f"{yaml_path}, field 'origin'")
    if abs(oyaw) > 1e-9:
        raise InputError(f"{yaml_path}, field 'origin': yaw {oyaw} is not supported (only 0)")
    mode = str(meta.get("mode", "trinary"))
    if mode not in ("trinary", "scale"):
        raise InputError(f"{yaml_path}, field 'mode': {mode!r} is not supported (trinary or scale)")
    negate = int(_num(meta, "negate", yaml_path)) if "negate" in meta else 0
    occ_t = _num(meta, "occupied_thresh", yaml_path) if "occupied_thresh" in meta else OCCUPIED_THRESH
    free_t = _num(meta, "free_thresh", yaml_path) if "free_thresh" in meta else FREE_THRESH
    if "image" not in meta:
        raise InputError(f"{yaml_path}: no 'image'")
    img_path = Path(str(meta["image"]))
    img_path = img_path if img_path.is_absolute() else yaml_path.parent / img_path
    if not img_path.exists():
        raise InputError(f"{yaml_path}, field 'image': {img_path} not found")
    v = read_map_image(img_path).astype(np.float32)  # bounded: bytes, pixels, no FIFO
    p = v / 255.0 if negate else (255.0 - v) / 255.0
    occ = (p > occ_t)[::-1]
    free = (p < free_t)[::-1]
    cfg = MapConfig(resolution=res, require_floor=False)
    grid = OccupancyGrid(cfg, (ox, oy), occ.shape)
    grid.logodds[occ] = cfg.l_clamp
    grid.logodds[free] = -cfg.l_clamp
    grid.known = occ | free
    grid.explored = grid.known.copy()
    grid.meta = {
        "kind": "imported",
        "frame": MapFrame(method="Nav2 map frame").as_dict(),
        "from": str(yaml_path),
    }
    return grid


MAX_GRID_CELLS = 100_000_000  # a live map larger than this (10 km x 10 km at 1 cm) is refused


def grid_from_occupancy(
    width: int, height: int, resolution: float, origin: tuple[float, float, float], data: Any, source: str
) -> OccupancyGrid:
    """A `nav_msgs/OccupancyGrid` (a live map_server's or SLAM's map) as the memory's map, as
    `import_map_server` reads files: cell values 0-100 are occupancy in percent (-1 unknown),
    occupied above `OCCUPIED_THRESH`, free below `FREE_THRESH`; row 0 is the row at the origin
    (the smallest y), as in the grid. A one-line `InputError` for a map that cannot be one."""
    if width <= 0 or height <= 0:
        raise InputError(f"{source}: empty map ({width}x{height})")
    if width * height > MAX_GRID_CELLS:
        raise InputError(f"{source}: {width}x{height} cells is more than {MAX_GRID_CELLS}")
    if not (isinstance(resolution, float | int) and 1e-3 <= resolution <= 10):
        raise InputError(f"{source}: resolution must be from 0.001 to 10 m, got {resolution}")
    ox, oy, oyaw = origin
    for corner in (ox, oy):
        check_coord(corner, f"{source}: origin")
    if abs(oyaw) > 1e-6:
        raise InputError(f"{source}: origin yaw {oyaw:g} is not supported (only 0)")
    cells = np.frombuffer(memoryview(data).cast("B") if not isinstance(data, np.ndarray) else data, np.int8)
    if cells.size != width * height:
        raise InputError(f"{source}: {cells.size} cells for a {width}x{height} map")
    v = cells.reshape(height, width).astype(np.int16)
    occ = v > OCCUPIED_THRESH * 100
    free = (v >= 0) & (v < FREE_THRESH * 100)
    cfg = MapConfig(resolution=float(resolution), require_floor=False)
    grid = OccupancyGrid(cfg, (float(ox), float(oy)), occ.shape)
    grid.logodds[occ] = cfg.l_clamp
    grid.logodds[free] = -cfg.l_clamp
    grid.known = occ | free
    grid.explored = grid.known.copy()
    grid.meta = {"kind": "imported", "frame": MapFrame(method="Nav2 map frame").as_dict(), "from": source}
    return grid
