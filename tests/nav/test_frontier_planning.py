import numpy as np
import pytest

from ravenmem.nav import MapConfig, OccupancyGrid, find_frontiers, frontier_mask, plan_path
from ravenmem.nav.frontier import cluster_frontiers


def _grid_from(rows: list[str], res: float = 0.25) -> OccupancyGrid:
    """'.' free, '#' obstacle, '?' unknown; row 0 is the bottom (lowest y)."""
    g = OccupancyGrid(
        MapConfig(resolution=res, require_floor=False), origin=(0.0, 0.0), shape=(len(rows), len(rows[0]))
    )
    for r, line in enumerate(rows):
        for c, ch in enumerate(line):
            if ch != "?":
                g.known[r, c] = True
                g.logodds[r, c] = 2.0 if ch == "#" else -2.0
    g.touch()
    return g


def test_frontier_cells_are_free_next_to_unknown() -> None:
    free = np.zeros((7, 7), bool)
    unknown = np.ones((7, 7), bool)
    free[2:5, 2:5] = True
    unknown[2:5, 2:5] = False
    m = frontier_mask(free, unknown)
    expect = free.copy()
    expect[3, 3] = False  # the centre has only free 4-neighbours
    assert np.array_equal(m, expect)
    # diagonal-only contact with unknown is not a frontier (4-neighbourhood)
    free2 = np.ones((3, 3), bool)
    unk2 = np.zeros((3, 3), bool)
    free2[0, 0], unk2[0, 0] = False, True
    m2 = frontier_mask(np.pad(free2, 1, constant_values=True), np.pad(unk2, 1))
    assert not m2[2, 2] and m2[1, 2] and m2[2, 1]


def test_clusters_are_separated_and_small_ones_dropped() -> None:
    m = np.zeros((10, 10), bool)
    m[0, 0:5] = True
    m[9, 9] = True
    m[5, 3:5] = True
    sizes = sorted(c.shape[0] for c in cluster_frontiers(m, min_size=1))
    assert sizes == [1, 2, 5]
    assert [c.shape[0] for c in cluster_frontiers(m, min_size=3)] == [5]


ROOMS = [
    "#################",
    "#.......#.......?",
    "#.......#.......?",
    "#.......#.......?",
    "#...............?",
    "#.......#.......?",
    "#.......#.......#",
    "#########???#####",
]


def test_nearest_reachable_frontier_first_by_path_length() -> None:
    g = _grid_from(ROOMS)
    robot = g.cell_to_world((3, 6))
    fs = find_frontiers(g, robot, robot_radius=0.2, min_size=2, reach=0.5)
    assert len(fs) == 2
    # The bottom gap (row 7, cols 9-11) and the right edge (col 16): both beyond the doorway.
    assert fs[0].cost_m <= fs[1].cost_m
    assert all(f.target_cell[1] >= 8 for f in fs)
    # blacklisting the nearest leaves the other
    rest = find_frontiers(g, robot, 0.2, 2, reach=0.5, blacklist=[fs[0].target], blacklist_radius=1.0)
    assert len(rest) == 1 and rest[0].target != fs[0].target


def test_unreachable_frontier_is_ignored() -> None:
    rows = [r.replace("#...............?", "#.......#.......?") for r in ROOMS]  # close the doorway
    g = _grid_from(rows)
    fs = find_frontiers(g, g.cell_to_world((3, 4)), robot_radius=0.2, min_size=2, reach=0.5)
    assert fs == []


def test_plan_path_reaches_goal_and_reports_length() -> None:
    g = _grid_from(ROOMS)
    start, goal = g.cell_to_world((3, 2)), g.cell_to_world((3, 14))
    p = plan_path(g, start, goal, robot_radius=0.2)
    assert p.ok and not p.snapped
    assert p.waypoints[0] == pytest.approx(start) and p.waypoints[-1] == pytest.approx(goal)
    assert p.length_m == pytest.approx(12 * 0.25, rel=0.05)  # straight through the doorway


def test_goal_in_obstacle_snaps_to_a_cell_that_sees_it() -> None:
    rows = [
        "###########",
        "#.........#",
        "#.........#",
        "#....#....#",  # a pillar; the goal is inside it
        "#.........#",
        "#.........#",
        "###########",
    ]
    g = _grid_from(rows)
    p = plan_path(g, g.cell_to_world((1, 1)), g.cell_to_world((3, 5)), robot_radius=0.1)
    assert p.ok and p.snapped and p.reason == ""
    gc = g.world_to_cell(*p.goal)
    assert abs(gc[0] - 3) + abs(gc[1] - 5) <= 2


def test_snapping_prefers_a_cell_with_line_of_sight() -> None:
    rows = [
        "##############",
        "#............#",
        "#............#",
        "#.......#???.#",
        "#.......#???.#",
        "#.......#???.#",  # goal (5, 9): unknown, just behind the wall at column 8
        "#.......#???.#",
        "##############",
    ]
    g = _grid_from(rows)
    p = plan_path(g, g.cell_to_world((5, 2)), g.cell_to_world((5, 9)), robot_radius=0.1, snap_radius=1.0)
    assert p.ok and p.snapped and p.reason == ""
    gc = g.world_to_cell(*p.goal)
    # the nearest reachable cell, (5, 7), is behind the wall; a cell that sees the goal wins
    assert gc[1] >= 9 and gc != (5, 7)


def test_unreachable_goal_is_a_clear_result() -> None:
    g = _grid_from(ROOMS)
    p = plan_path(g, g.cell_to_world((3, 2)), (40.0, 40.0), robot_radius=0.2)
    assert not p.ok and "unreachable" in p.reason
    empty = OccupancyGrid()
    assert not plan_path(empty, (0, 0), (1, 1), 0.2).ok
