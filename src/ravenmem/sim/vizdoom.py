"""ViZDoom backend: a Freedoom map as a CPU-only, offline world for a simulated robot.

Scale: 1 Doom map unit = 1/32 m (the player is 56 units = 1.75 m tall, 16 units = 0.5 m in
radius, and sees from 41 units = 1.28 m). World frame: Doom's x (east) and y (north) in metres,
yaw from Doom's ANGLE (0 = east, counter-clockwise). Depth: ViZDoom's 8-bit depth buffer is
linear in distance along the optical axis; its scale was measured against the map's own wall
segments (docs/navigation.md: ViZDoom conventions) and one level is about 0.23 m. Monsters are off (`-nomonsters`)
and the player is invulnerable (`god`), so the robot only explores.

ViZDoom writes a config file (`_vizdoom.ini`) and a `_vizdoom/` folder into the working
directory of the game process; both go into a private temporary folder instead (removed on
`close`), so running the simulator leaves nothing in the user's folder.
"""

from __future__ import annotations

import math
import os
import tempfile
import time
from collections import defaultdict
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

import numpy as np

from ..errors import InputError, require
from ..types import Intrinsics, Pose
from .base import ENVIRONMENTS, Observation, RobotSpec, SceneObject

UNITS_PER_M = 32.0
TICRATE = 35.0
# depth (map units) = DEPTH_SCALE * buffer value + DEPTH_OFFSET; fitted on freedoom2 MAP01.
DEPTH_SCALE = 7.15
DEPTH_OFFSET = 8.5
# The renderer's vertical focal length is this much longer than the horizontal one (pixels are
# not square in Doom's projection); fitted on floor pixels of freedoom2 MAP02 (docs/navigation.md: ViZDoom conventions).
PIXEL_ASPECT = 1.15
SPEED_PER_DELTA = 0.32  # map units per tic of steady speed per unit of MOVE_FORWARD_BACKWARD_DELTA
STEP_UNITS, HEIGHT_UNITS, RADIUS_UNITS, VIEW_UNITS = 24.0, 56.0, 16.0, 41.0


@contextmanager
def _working_dir(path: str) -> Iterator[None]:
    """Run a block with `path` as the working directory (the game process inherits it)."""
    old = os.getcwd()
    os.chdir(path)
    try:
        yield
    finally:
        os.chdir(old)


def _doom_camera(width: int, height: int, hfov_deg: float) -> Intrinsics:
    """Doom's camera: the horizontal field of view, and taller-than-wide pixels."""
    base = Intrinsics.from_fov(width, height, hfov_deg)
    return Intrinsics(base.fx, base.fx * PIXEL_ASPECT, base.cx, base.cy, width, height)


def _parse_spec(spec: str) -> tuple[str, str]:
    """'freedoom2/MAP01', 'freedoom1/E1M1' or '/path/to/file.wad/MAP01' -> (wad path, map)."""
    vzd = require("vizdoom", "sim")
    spec = spec or "freedoom2/MAP01"
    wad, _, level = spec.rpartition("/")
    if not wad:
        wad, level = spec, "MAP01"
    if wad in ("freedoom1", "freedoom2", "doom2", "doom"):
        path = os.path.join(os.path.dirname(vzd.__file__), f"{wad}.wad")  # type: ignore[attr-defined]
    else:
        path = wad if wad.endswith(".wad") else wad + ".wad"
    if not os.path.isfile(path):
        raise InputError(f"vizdoom:{spec}: WAD file {path} not found (use freedoom1/E1M1 or freedoom2/MAP01)")
    maps = wad_maps(path)
    if level.upper() not in maps:
        raise InputError(
            f"vizdoom:{spec}: no map {level.upper()} in {os.path.basename(path)} "
            f"(it has {', '.join(sorted(maps)[:4])}{', ...' if len(maps) > 4 else ''})"
        )
    return path, level.upper()


def wad_maps(path: str) -> set[str]:
    """Map names in a WAD (a map is a marker lump followed by a THINGS lump)."""
    import struct

    try:
        with open(path, "rb") as f:
            magic, n, off = struct.unpack("<4sii", f.read(12))
            if magic not in (b"IWAD", b"PWAD") or n < 0 or off < 12:
                raise InputError(f"{path}: not a WAD file")
            f.seek(off)
            raw = f.read(16 * n)
    except (OSError, struct.error) as e:
        raise InputError(f"{path}: unreadable WAD ({e})") from e
    names = [
        raw[i * 16 + 8 : i * 16 + 16].rstrip(b"\0").decode("ascii", "replace") for i in range(len(raw) // 16)
    ]
    return {a for a, b in zip(names, names[1:]) if b == "THINGS"}


class VizDoomEnv:
    """A Doom level with the player as the robot. `step` holds the command `frame_skip` tics."""

    def __init__(
        self,
        spec: str = "freedoom2/MAP01",
        width: int = 320,
        height: int = 240,
        frame_skip: int = 2,
        max_speed: float = 2.5,
        start_time: float | None = None,
        min_label_pixels: int = 80,
    ) -> None:
        vzd = require("vizdoom", "sim")
        self._vzd = vzd
        wad, level = _parse_spec(spec)
        self.name = f"vizdoom:{os.path.splitext(os.path.basename(wad))[0]}/{level}"
        res = getattr(vzd.ScreenResolution, f"RES_{width}X{height}", None)  # type: ignore[attr-defined]
        if res is None:
            raise InputError(f"{self.name}: unsupported resolution {width}x{height} (try 320x240 or 640x480)")
        self._wad, self._level, self._res = wad, level, res
        self._scratch = tempfile.TemporaryDirectory(prefix="ravenmem-vizdoom-")
        g = self._new_game(ground_truth=False)
        try:
            self._init(g)
        except Exception as e:  # vizdoom raises its own exception types for bad WADs/maps
            self._scratch.cleanup()
            raise InputError(f"{self.name}: ViZDoom could not start ({e})") from e
        self._game = g
        self.frame_skip = max(1, int(frame_skip))
        self.min_label_pixels = int(min_label_pixels)
        self.robot = RobotSpec(
            radius=RADIUS_UNITS / UNITS_PER_M,
            height=HEIGHT_UNITS / UNITS_PER_M,
            step_height=STEP_UNITS / UNITS_PER_M,
            camera_height=VIEW_UNITS / UNITS_PER_M,
            max_speed=float(max_speed),
        )
        self.intrinsics = _doom_camera(width, height, 90.0)
        self._start_time = start_time
        self._t0 = 0.0
        self._steps = 0
        self._objects: list[SceneObject] | None = None
        self._by_place: dict[tuple[str, int, int], int] = {}
        self._lines: list[tuple[float, float, float, float, bool]] = []
        self._last: Observation | None = None

    def _init(self, g: Any) -> None:
        """Start a game process with its files in the scratch folder, not the user's."""
        with _working_dir(self._scratch.name):
            g.init()

    def _new_game(self, ground_truth: bool) -> Any:
        """The robot's game renders RGB, depth and labels; a second, short-lived game reads the
        level's objects and sectors once (asking for them every tic would double the cost)."""
        vzd = self._vzd
        g = vzd.DoomGame()  # type: ignore[attr-defined]
        g.set_doom_game_path(self._wad)
        g.set_doom_map(self._level)
        g.set_doom_config_path(os.path.join(self._scratch.name, "_vizdoom.ini"))
        g.set_screen_resolution(self._res)
        g.set_screen_format(vzd.ScreenFormat.RGB24)  # type: ignore[attr-defined]
        g.set_depth_buffer_enabled(not ground_truth)
        g.set_labels_buffer_enabled(not ground_truth)
        g.set_objects_info_enabled(ground_truth)
        g.set_sectors_info_enabled(ground_truth)
        g.set_window_visible(False)
        g.set_sound_enabled(False)
        g.set_render_hud(False)
        g.set_render_weapon(False)
        g.set_render_crosshair(False)
        g.set_render_messages(False)
        g.set_episode_timeout(0)
        g.set_mode(vzd.Mode.PLAYER)  # type: ignore[attr-defined]
        g.add_game_args("-nomonsters +sv_cheats 1 +movebob 0")
        B, V = vzd.Button, vzd.GameVariable  # type: ignore[attr-defined]
        g.set_available_buttons([B.MOVE_FORWARD_BACKWARD_DELTA, B.TURN_LEFT_RIGHT_DELTA])
        g.set_available_game_variables(
            [V.POSITION_X, V.POSITION_Y, V.POSITION_Z, V.ANGLE, V.CAMERA_POSITION_Z, V.CAMERA_FOV]
        )
        return g

    def _load_ground_truth(self) -> None:
        g = self._new_game(ground_truth=True)
        try:
            self._init(g)
            g.new_episode()
            st = g.get_state()
            self._objects = [
                SceneObject(
                    int(o.id),
                    str(o.name),
                    o.position_x / UNITS_PER_M,
                    o.position_y / UNITS_PER_M,
                    o.position_z / UNITS_PER_M,
                )
                for o in st.objects
                if o.name != "DoomPlayer"
            ]
            self._lines = self._walls(st.sectors)
            # Object ids differ between game instances: labels are matched by name and place.
            self._by_place = {
                (str(o.name), round(o.position_x), round(o.position_y)): int(o.id)
                for o in st.objects
                if o.name != "DoomPlayer"
            }
        finally:
            g.close()

    # --- protocol -------------------------------------------------------------------------
    def reset(self) -> Observation:
        g = self._game
        g.new_episode()
        g.send_game_command("god")
        g.make_action([0.0, 0.0], 10)  # the first tics of an episode ignore input
        if g.get_state() is None:
            raise InputError(f"{self.name}: the episode ended at once (is this map playable?)")
        self._t0 = time.time() if self._start_time is None else float(self._start_time)
        self._steps = 0
        st = g.get_state()
        fov = float(st.game_variables[5])
        if abs(fov - 90.0) > 0.5:
            self.intrinsics = _doom_camera(self.intrinsics.width, self.intrinsics.height, fov)
        if self._objects is None:
            self._load_ground_truth()
        return self.observe()

    def observe(self) -> Observation:
        st = self._game.get_state()
        if st is None:
            if self._last is None:
                raise InputError(f"{self.name}: no observation (call reset first)")
            return self._last
        x, y, z, ang, cam_z, _ = (float(v) for v in st.game_variables)
        raw = st.depth_buffer
        depth = np.where(
            (raw > 0) & (raw < 255), (raw.astype(np.float32) * DEPTH_SCALE + DEPTH_OFFSET) / UNITS_PER_M, 0.0
        ).astype(np.float32)
        yaw = math.atan2(math.sin(math.radians(ang)), math.cos(math.radians(ang)))
        boxes: dict[int, tuple[int, int, int, int]] = {}
        for lb in st.labels or []:
            box = (int(lb.x), int(lb.y), int(lb.width), int(lb.height))
            k = (lb.object_name, round(lb.object_position_x), round(lb.object_position_y))
            if box[2] * box[3] >= self.min_label_pixels and k in self._by_place:
                oid = self._by_place[k]
                old = boxes.get(oid)
                if old is None or old[2] * old[3] < box[2] * box[3]:
                    boxes[oid] = box
        visible = tuple(sorted(boxes))
        self._last = Observation(
            rgb=np.ascontiguousarray(st.screen_buffer),
            depth=depth,
            pose=Pose(x / UNITS_PER_M, y / UNITS_PER_M, cam_z / UNITS_PER_M, yaw),
            t=self._t0 + st.tic / TICRATE,
            step=self._steps,
            visible=visible,
            floor_z=z / UNITS_PER_M,
            visible_boxes=boxes,
        )
        return self._last

    def step(self, forward: float, turn: float) -> Observation:
        fwd = max(-1.0, min(1.0, float(forward)))
        speed_units_per_tic = fwd * self.robot.max_speed * UNITS_PER_M / TICRATE
        delta = speed_units_per_tic / SPEED_PER_DELTA
        # One call renders once; the turn is spread over the tics it is held for.
        self._game.make_action([delta, -math.degrees(float(turn)) / self.frame_skip], self.frame_skip)
        self._steps += 1
        return self.observe()

    @property
    def wad_path(self) -> str:
        """The WAD file this level comes from (its sprites picture the objects)."""
        return self._wad

    def view_from(self, x: float, y: float, yaw: float) -> Observation:
        """What the camera sees from (x, y) facing `yaw` (teleports the player: for making query
        pictures and tests, not for the robot, which must drive)."""
        g = self._game
        warp = f"warp {x * UNITS_PER_M:.1f} {y * UNITS_PER_M:.1f}"
        g.send_game_command(warp)
        g.make_action([0.0, 0.0], 20)  # the player keeps its momentum through a warp: let it stop
        g.send_game_command(warp)
        g.make_action([0.0, 0.0], 6)  # and the view height settle after the jump
        cur = self.observe().pose.yaw
        turn = math.atan2(math.sin(yaw - cur), math.cos(yaw - cur))
        g.make_action([0.0, -math.degrees(turn)], 1)
        g.make_action([0.0, 0.0], 2)
        return self.observe()

    def objects(self) -> list[SceneObject]:
        if self._objects is None:
            self._load_ground_truth()
        return list(self._objects or [])

    def close(self) -> None:
        self._game.close()
        self._scratch.cleanup()

    # --- ground truth for tests and coverage ----------------------------------------------
    @staticmethod
    def _walls(sectors: object) -> list[tuple[float, float, float, float, bool]]:
        """Every line (metres) and whether the robot can cross it: one-sided and blocking
        lines cannot; two-sided ones can when the step is low enough and the gap tall enough."""
        by_key: dict[tuple, list] = defaultdict(list)
        for sec in sectors:  # type: ignore[attr-defined]
            for ln in sec.lines:
                key = tuple(sorted([(ln.x1, ln.y1), (ln.x2, ln.y2)]))
                by_key[key].append((sec, ln.is_blocking))
        out = []
        for ((x1, y1), (x2, y2)), sides in by_key.items():
            passable = len(sides) == 2 and not any(b for _, b in sides)
            if passable:
                floors = [s.floor_height for s, _ in sides]
                ceils = [s.ceiling_height for s, _ in sides]
                passable = (
                    abs(floors[0] - floors[1]) <= STEP_UNITS and min(ceils) - max(floors) >= HEIGHT_UNITS
                )
            out.append((x1 / UNITS_PER_M, y1 / UNITS_PER_M, x2 / UNITS_PER_M, y2 / UNITS_PER_M, passable))
        return out

    def wall_segments(self, solid_only: bool = True) -> np.ndarray:
        """(n, 4) array of x1, y1, x2, y2 in metres: lines the robot cannot cross (or all)."""
        if self._objects is None:
            self._load_ground_truth()
        rows = [ln[:4] for ln in self._lines if not (solid_only and ln[4])]
        return np.asarray(rows, np.float64).reshape(-1, 4)


@ENVIRONMENTS.register("vizdoom")
def _make_vizdoom(spec: str = "", **kwargs: object) -> VizDoomEnv:
    return VizDoomEnv(spec or "freedoom2/MAP01", **kwargs)  # type: ignore[arg-type]
