"""The simulated operator's lasso in a frame's view: the boards of a fence inside a hedge, which no
prism separates, and nothing behind them."""

from __future__ import annotations

import numpy as np

from bench.effort.view_lasso import plan_view_lasso

BUSH, BUILDING, FENCE, GROUND = 0, 1, 2, 3


def _wall(distance: float, az: np.ndarray, el: np.ndarray) -> np.ndarray:
    """Points of a wall across the x axis at `distance`, one per (azimuth, elevation) ray (rad)."""
    a, e = np.meshgrid(az, el)
    return np.column_stack([np.full(a.size, distance), distance * np.tan(a.ravel()), distance * np.tan(e.ravel())])


def _hedge_with_boards(T_world_lidar: np.ndarray):
    """A hedge at 10 m whose middle rows hold fence boards between its leaves (the boards' rows
    alternate with the leaves' at one range: no prism holds the boards alone), taken for bush; a
    building at 14 m seen through the gaps between the boards (every third ray of their rows)."""
    az = np.deg2rad(np.arange(-10.0, 10.0, 0.2))
    el = np.deg2rad(np.arange(-8.0, 4.0, 0.4))
    wall = _wall(10.0, az, el)
    rows, cols = np.repeat(np.arange(len(el)), len(az)), np.tile(np.arange(len(az)), len(el))
    middle = (np.abs(np.rad2deg(az[cols])) < 3.0) & (rows >= 10) & (rows <= 18)
    gap = middle & (cols % 3 == 0)
    board = middle & ~gap & (rows % 2 == 0)
    lidar = np.concatenate([wall[~gap], wall[gap] * 1.4])
    true = np.concatenate([np.where(board, FENCE, BUSH)[~gap], np.full(gap.sum(), BUILDING)]).astype(np.uint8)
    current = np.where(true == FENCE, BUSH, true).astype(np.uint8)
    world = lidar @ T_world_lidar[:3, :3].T + T_world_lidar[:3, 3]
    return world, true, current


def test_view_lasso_paints_the_boards_of_one_frame_and_nothing_behind_or_around_them():
    T = np.eye(4)
    T[:3, :3] = [[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]  # the sensor faces world +y
    T[:3, 3] = [5.0, -3.0, 1.7]
    world, true, current = _hedge_with_boards(T)
    boards = true == FENCE
    lasso = plan_view_lasso(world, true, current, T, 4, 4)
    assert lasso is not None and lasso.class_ == FENCE
    inside = lasso.rule(4).labels(world, None, 4)
    assert not lasso.rule(4).labels(world, None, 3).any()  # another frame's points
    assert (inside & boards).sum() >= boards.sum() // 5  # a row of boards or more, whole (five rows)
    assert lasso.gain == int((inside & boards).sum() - (inside & ~boards).sum())
    assert (inside & ~boards).sum() <= 0.05 * (inside & boards).sum()
    # lasso by lasso, every board is painted and the building behind keeps its class
    for _ in range(20):
        lasso = plan_view_lasso(world, true, current, T, 4, 4)
        if lasso is None or lasso.gain < 5:
            break
        current[lasso.rule(4).labels(world, None, 4)] = lasso.class_
    assert (current == true).mean() >= 0.99 and (current[true == BUILDING] == BUILDING).all()
