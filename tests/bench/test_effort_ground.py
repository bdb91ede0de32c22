"""The simulated operator's lasso: it traces the area that puts the most seen points right."""

from __future__ import annotations

import numpy as np

from bench.effort.ground import Lasso, plan
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


def test_prism_lifts_over_a_hedge_its_ground_and_the_car_beside_it_left_out():
    from bench.effort.ground import plan_prism

    CAR, BUSH, GROUND = 0, 1, 2  # two object classes, then ground
    rng = np.random.default_rng(1)
    hedge = np.column_stack([rng.uniform(0, 20, 6000), rng.uniform(5, 7, 6000), rng.uniform(0.3, 2.0, 6000)])
    car = np.column_stack([rng.uniform(2, 6, 2000), rng.uniform(1, 3, 2000), rng.uniform(0.2, 1.5, 2000)])
    road = np.column_stack([rng.uniform(0, 20, 8000), rng.uniform(0, 8, 8000), rng.normal(0.0, 0.02, 8000)])
    world = np.concatenate([hedge, car, road])
    true = np.repeat(np.array([BUSH, CAR, GROUND], np.uint8), [6000, 2000, 8000])
    current = true.copy()
    current[:6000] = CAR  # the hedge shows as car; the car and the road are right
    lasso = plan_prism(world, true, current, objects=2, n_classes=3)
    assert lasso is not None and lasso.class_ == BUSH and lasso.heights is not None
    low, high = lasso.heights
    assert 0.25 <= low <= 0.35 and 1.95 <= high <= 2.0  # the hedge's own heights: the road stays below
    inside = points_in_polygon(world[:, :2], lasso.polygon) & (world[:, 2] >= low) & (world[:, 2] <= high)
    assert inside[:6000].mean() >= 0.93 and not inside[6000:].any()  # all but its 1st and 99th height percentiles
    assert lasso.gain == int(inside[:6000].sum())
    assert plan_prism(world, true, true, objects=2, n_classes=3) is None  # nothing wrong: nothing to draw


def test_replay_paints_a_wrong_hedge_unless_a_decided_track_holds_it():
    from bench.effort.replay_regions import replay
    from pipeline.label_sets import preset

    ls = preset("paper")
    car, bush, ground = ls.index("car"), ls.index("bush"), ls.ground_index
    rng = np.random.default_rng(2)
    hedge = np.column_stack([rng.uniform(0, 20, 4000), rng.uniform(5, 7, 4000), rng.uniform(0.3, 2.0, 4000)])
    road = np.column_stack([rng.uniform(0, 20, 4000), rng.uniform(0, 8, 4000), rng.normal(0.0, 0.02, 4000)])
    state = {"world": np.concatenate([hedge, road]), "true": np.repeat(np.array([bush, ground], np.uint8), 4000),
             "current": np.repeat(np.array([car, ground], np.uint8), 4000), "decided": np.zeros(8000, bool)}
    rows = replay(state, ls, regions=3, min_gain=200, undecided_only=False)
    assert rows[0]["non_ground_right"] == 0.0 and rows[-1]["non_ground_right"] >= 0.93
    assert all(r["ground_right"] == 1.0 for r in rows)  # the prism stays above the road
    state["decided"][:4000] = True  # a reviewed track holds the hedge
    assert len(replay(state, ls, regions=3, min_gain=200, undecided_only=True)) == 1  # nothing to draw


def test_prism_over_low_bushes_keeps_the_lawn_under_them_out():
    """Bushes 0.1-1.2 m on a lawn of terrain (a ground class) shown wrongly as road: the prism's
    bottom rises above the lawn, which a lasso labels better."""
    from bench.effort.ground import plan_prism

    CAR, BUSH, ROAD, TERRAIN = 0, 1, 2, 3  # two object classes, then two ground classes
    rng = np.random.default_rng(3)
    bush = np.column_stack([rng.uniform(0, 10, 5000), rng.uniform(0, 4, 5000), rng.uniform(0.1, 1.2, 5000)])
    lawn = np.column_stack([rng.uniform(0, 10, 5000), rng.uniform(0, 4, 5000), rng.uniform(0.0, 0.25, 5000)])
    world = np.concatenate([bush, lawn])
    true = np.repeat(np.array([BUSH, TERRAIN], np.uint8), 5000)
    current = np.repeat(np.array([CAR, ROAD], np.uint8), 5000)  # both wrong
    lasso = plan_prism(world, true, current, objects=2, n_classes=4)
    assert lasso is not None and lasso.class_ == BUSH
    inside = points_in_polygon(world[:, :2], lasso.polygon) & (world[:, 2] >= lasso.heights[0]) & (world[:, 2] <= lasso.heights[1])
    assert inside[5000:].sum() <= 0.1 * inside[:5000].sum()  # little of the lawn under it
    assert lasso.gain == int(inside[:5000].sum() - inside[5000:].sum())


BUSH, FENCE = 1, 2  # of car, bush, fence (objects), then ground, in the fence-and-hedge scenes


def _fence_behind_hedge(seed: int, hedge_points: int, hedge_back: float,
                        fence: tuple[float, float]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A hedge 20 m long from y = 5 m to `hedge_back` and 1,200 points of fence between the y of
    `fence`: world points, true classes, and current classes (all bush: the fence shows as bush)."""
    rng = np.random.default_rng(seed)
    n = hedge_points
    hedge = np.column_stack([rng.uniform(0, 20, n), rng.uniform(5.0, hedge_back, n), rng.uniform(0.3, 1.8, n)])
    wire = np.column_stack([rng.uniform(0, 20, 1200), rng.uniform(*fence, 1200), rng.uniform(0.3, 1.2, 1200)])
    true = np.repeat(np.array([BUSH, FENCE], np.uint8), [n, 1200])
    return np.concatenate([hedge, wire]), true, np.full(len(true), BUSH, np.uint8)


def test_prism_traces_a_fence_along_a_hedge_on_the_finer_grid():
    """A fence 0.25 m behind a hedge shows as the hedge's bush: no 0.5 m cell is mostly fence,
    some 0.35 m cells are, so the prism that labels it is traced on those."""
    from bench.effort.ground import plan_prism

    world, true, current = _fence_behind_hedge(4, 6000, hedge_back=6.2, fence=(6.35, 6.45))
    lasso = plan_prism(world, true, current, objects=3, n_classes=4)
    assert lasso is not None and lasso.class_ == FENCE
    inside = points_in_polygon(world[:, :2], lasso.polygon)
    assert inside[6000:].mean() >= 0.85 and inside[:6000].sum() <= 0.15 * inside[6000:].sum()
    assert lasso.gain >= 900  # on the 0.5 m grid alone: 233, the hedge's edge taken with it


def test_prism_on_a_finer_grid_reaches_a_fence_the_operators_grids_cannot():
    """A fence 0.1 m behind a dense hedge: every 0.5 m and 0.35 m cell that holds it is mostly
    hedge, so the operator's grids find no fence area; a 0.2 m grid (`cells`, as replay_regions
    measures what prisms can reach) does."""
    from bench.effort.ground import plan_prism

    world, true, current = _fence_behind_hedge(5, 12000, hedge_back=6.18, fence=(6.28, 6.32))
    coarse = plan_prism(world, true, current, objects=3, n_classes=4)
    assert coarse is None or coarse.gain < 300
    fine = plan_prism(world, true, current, objects=3, n_classes=4, cells=(0.5, 0.35, 0.2), vertices=1000)
    assert fine is not None and fine.class_ == FENCE and fine.gain >= 900


def test_operator_draws_a_region_when_it_puts_more_right_than_a_review_did():
    from bench.effort.operator import Operator

    op = Operator(None, None, None, 1, [], None)  # type: ignore[arg-type]  # _need reads only its counts
    assert op._need(10_000) == 20  # its first look: region_share of the seen object points
    op.counts.edits, op._right = 10, 5_000
    op._since = (10, 5_000)  # the look ended after 10 actions
    assert op._need(10_000) == 20  # no action since: still the share
    op.counts.edits, op._right = 15, 5_600  # five reviews put 600 more points right
    assert op._need(10_000) == 120
    op._right = 4_000  # the reviews made it worse: any region that puts a point right is worth more
    assert op._need(10_000) == 1


def test_operator_keeps_the_bar_of_its_reviews_through_a_look_from_above(monkeypatch):
    from bench.effort.operator import Operator, Policy

    op = Operator(None, None, None, 1, [], None, policy=Policy(prisms_per_frame=9))  # type: ignore[arg-type]
    op.counts.edits, op._right, op._since = 15, 5_600, (10, 5_000)  # five reviews put 600 points right: 120 each
    offered, drawn = [500, 200, 130, 90], []
    square = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])

    def best() -> tuple[Lasso, int]:
        op._right = 5_600 + sum(drawn)  # each region drawn put its gain right
        return Lasso(square, 0, offered[len(drawn)], (0.0, 1.0)), 10_000

    def draw(path: str, body: dict) -> dict:
        op.counts.edits += 1
        drawn.append(offered[len(drawn)])
        return {}

    monkeypatch.setattr(op, "_best_region", best)
    monkeypatch.setattr(op, "_edit", draw)
    assert op.region_pass()
    # 500, 200 and 130 beat a review's 120, 90 does not; a bar that counted the regions of this
    # look would have risen to 183 after the first and stopped at 130
    assert drawn == [500, 200, 130]


def test_losses_count_wrong_non_ground_points_by_true_exported_class_and_source():
    from bench.effort.losses import tally
    from pipeline.label_sets import preset

    ls = preset("paper")
    bush, fence, ground = (ls.point_class_names.index(c) for c in ("bush", "unknown", "ground"))
    true = np.array([bush, bush, bush, fence, fence, ground, UNLABELLED], np.uint8)
    exported = np.array([bush, ground, ground, bush, UNLABELLED, bush, bush], np.uint8)
    source = np.array([1, 4, 4, 2, 0, 4, 1], np.uint8)
    wrong, total = tally(true, exported, source, ls)
    assert total == 5  # ground and unlabelled truth do not count
    assert wrong == {(bush, ground, 4): 2, (fence, bush, 2): 1, (fence, UNLABELLED, 0): 1}
    # the ground points' losses: the one ground point, exported as bush (source 4: predicted)
    assert tally(true, exported, source, ls, ground=True) == ({(ground, bush, 4): 1}, 1)


def test_score_export_counts_the_labelled_points_and_those_right_on_each_side_of_the_ground():
    from pathlib import Path
    from types import SimpleNamespace

    from bench.effort.score import score_export
    from bench.effort.service import Export
    from bench.effort.truth import FrameTruth
    from pipeline.label_sets import preset

    ls = preset("paper")
    bush, car, ground = (ls.point_class_names.index(c) for c in ("bush", "car", "ground"))
    true = np.array([bush, bush, car, ground, ground, UNLABELLED], np.uint8)
    words = np.array([70, 40, 10, 40, 10, 0], np.uint32)  # SemanticKITTI: vegetation, road, car, road, car
    truth = SimpleNamespace(label_set=ls, labelled={"000000": FrameTruth(true, None, Path("000000.label"))})
    s = score_export(Export({"000000": words}, {}, {}, b""), truth)
    assert (s["non_ground_points"], s["non_ground_right_points"]) == (3, 2)  # the unlabelled row counts nowhere
    assert (s["ground_points"], s["ground_right_points"]) == (2, 1)
    assert s["non_ground_right"] == round(2 / 3, 4) and s["ground_right"] == 0.5
