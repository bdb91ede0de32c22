"""The simulated operator's lasso: it traces the area that puts the most seen points right."""

from __future__ import annotations

import numpy as np

from bench.effort.ground import plan
from pipeline.classes import UNLABELLED
from pipeline.regions import points_in_polygon

ROAD, WALK = 0, 1


def test_lasso_traces_a_wrongly_labelled_strip_beside_the_road():
    rng = np.random.default_rng(0)
    xy = rng.uniform([0, 0], [40, 12], size=(40000, 2))
    true = np.where(xy[:, 1] > 8, WALK, ROAD).astype(np.uint8)  # a sidewalk along y > 8
    current = np.full(len(xy), ROAD, np.uint8)  # everything shows as road
    true[::50] = UNLABELLED
    lasso = plan(xy, true, current, 2)
    assert lasso is not None and lasso.class_ == WALK
    inside = points_in_polygon(xy, lasso.polygon)
    walk = (true == WALK)
    assert (inside & walk).sum() >= 0.97 * walk.sum()  # the strip's points are inside
    assert (inside & (true == ROAD)).sum() <= 0.05 * walk.sum()  # the road's stay outside
    assert lasso.gain == int((inside & walk).sum() - (inside & (true == ROAD)).sum())
    # once the strip shows as sidewalk nothing is left to draw
    assert plan(xy, true, np.where(walk, WALK, current).astype(np.uint8), 2) is None
