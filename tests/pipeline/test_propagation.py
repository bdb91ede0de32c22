"""Every point's class and source: its track's decision, the nearest decided point, the
prediction, the ground class, or none."""

from __future__ import annotations

import numpy as np

from pipeline.propagation import (
    NONE,
    SOURCE,
    NearestLabel,
    PointLabels,
    Rules,
    TrackClasses,
    resolve_frame,
    thin,
)

# a reviewed car (track 1) at x = 0..1, a pending track 2 predicted bush at x = 10..11, and loose points
CAR, BUSH, GROUND_CLASS = 1, 4, 7


def _frame():
    world = np.array([
        [0.0, 0, 1], [1.0, 0, 1],  # track 1 (reviewed car)
        [10.0, 0, 1], [11.0, 0, 1],  # track 2 (predicted bush)
        [1.2, 0, 1],  # no track, 0.2 m from the car
        [3.0, 0, 1],  # no track, far from everything
        [11.25, 0, 1],  # no track, 0.25 m from the predicted bush
        [1.05, 0, 0.95],  # ground point 0.07 m from the car
        [1.45, 0, 1],  # ground point 0.45 m from the car, 0.25 m from the point propagated to x = 1.2
    ])
    track = np.array([1, 1, 2, 2, 0, 0, 0, 0, 0])
    ground = np.array([False] * 7 + [True, True])
    decided = TrackClasses.of([(1, CAR, SOURCE["reviewed"], 1.0)])
    predicted = TrackClasses.of([(2, BUSH, SOURCE["predicted"], 0.8)])
    return track, ground, world, decided, predicted


def _field(world, track, decided):
    from pipeline.propagation import decided_labels

    return NearestLabel(*thin(world, decided_labels(track, decided), 0.0))


def test_propagation_gives_each_point_the_nearest_source():
    track, ground, world, decided, predicted = _frame()
    rules = Rules(far_radius=0.0)
    out = resolve_frame(track, ground, world, decided, predicted, _field(world, track, decided), rules, GROUND_CLASS)
    assert out.class_.tolist() == [CAR, CAR, BUSH, BUSH, CAR, NONE, BUSH, CAR, GROUND_CLASS]
    names = {v: k for k, v in SOURCE.items()}
    assert [names[s] for s in out.source] == ["reviewed", "reviewed", "predicted", "predicted", "propagated", "none",
                                             "predicted", "propagated", "ground"]
    assert np.allclose(out.confidence[[2, 3, 6]], 0.8)


def test_propagation_far_radius_reaches_isolated_points_but_no_ground():
    track, ground, world, decided, predicted = _frame()
    world = np.vstack([world, [[1.0, 0, -2.0]]])  # a ground point 3 m below the car
    track, ground = np.append(track, 0), np.append(ground, True)
    field = _field(world, track, decided)
    near = resolve_frame(track, ground, world, decided, predicted, field, Rules(far_radius=0.0), GROUND_CLASS)
    far = resolve_frame(track, ground, world, decided, predicted, field, Rules(far_radius=2.0), GROUND_CLASS)
    assert near.class_[5] == NONE
    # x = 3 is 1.8 m from the car's point propagated to x = 1.2: within 2 m, beyond the 1 m radius
    assert far.class_[5] == CAR and far.source[5] != SOURCE["none"]
    assert far.class_[9] == GROUND_CLASS and far.source[9] == SOURCE["ground"]
    keep = np.arange(len(track)) != 5
    assert np.array_equal(near.class_[keep], far.class_[keep])


def test_propagation_off_leaves_untracked_points_without_a_class():
    track, ground, world, decided, predicted = _frame()
    rules = Rules(radius=0.0, ground_radius=0.0, far_radius=0.0)
    out = resolve_frame(track, ground, world, decided, predicted, _field(world, track, decided), rules, None)
    assert out.class_.tolist() == [CAR, CAR, BUSH, BUSH, NONE, NONE, NONE, NONE, NONE]


def test_propagation_reaches_across_frames_through_the_world_field():
    track, ground, world, decided, predicted = _frame()
    other = PointLabels(np.array([CAR], np.uint8), np.array([SOURCE["reviewed"]], np.uint8), np.ones(1, np.float32))
    field = NearestLabel(np.array([[3.1, 0, 1]]), other)  # the car seen in another frame reaches x = 3
    none = TrackClasses.of([])
    out = resolve_frame(track, ground, world, none, none, field, Rules(), None)
    assert out.class_[5] == CAR and out.source[5] == SOURCE["propagated"]


def test_propagation_thin_keeps_one_point_per_voxel():
    pts = np.array([[0.0, 0, 0], [0.01, 0, 0], [1.0, 0, 0], [5.0, 0, 0]])
    lab = PointLabels(np.array([1, 1, 2, NONE], np.uint8), np.ones(4, np.uint8), np.ones(4, np.float32))
    kept, kept_lab = thin(pts, lab, 0.05)
    assert len(kept) == 2 and kept_lab.class_.tolist() == [1, 2]


def test_propagation_ground_points_take_a_nearby_decision_but_never_a_prediction():
    # a bush segment and two ground points 0.1 m and 0.5 m from it
    world = np.array([[10.0, 0, 1], [10.1, 0, 0.9], [10.5, 0, 0.9]])
    track, ground = np.array([2, 0, 0]), np.array([False, True, True])
    bush = TrackClasses.of([(2, BUSH, SOURCE["reviewed"], 1.0)])
    predicted_bush = TrackClasses.of([(2, BUSH, SOURCE["predicted"], 0.8)])
    for field in (None, _field(world, track, bush)):  # this frame's decisions, or the world search's
        out = resolve_frame(track, ground, world, bush, TrackClasses.of([]), field, Rules(), GROUND_CLASS)
        assert out.class_.tolist() == [BUSH, BUSH, GROUND_CLASS]
        assert out.source[1] == SOURCE["propagated"]
    # a prediction stops at the ground (pipeline.propagation, step 4)
    out = resolve_frame(track, ground, world, TrackClasses.of([]), predicted_bush, None, Rules(), GROUND_CLASS)
    assert out.class_.tolist() == [BUSH, GROUND_CLASS, GROUND_CLASS]
    assert out.source.tolist() == [SOURCE["predicted"], SOURCE["ground"], SOURCE["ground"]]


def test_ground_region_labels_the_ground_points_inside_it_and_nothing_else():
    from pipeline.propagation import GroundRegion

    track, ground, world, decided, predicted = _frame()
    field = _field(world, track, decided)
    # a square around x = 0.5..1.6 holds ground points 7 and 8, car points 0 and 1 and loose point 4
    square = np.array([[0.5, -1.0], [1.6, -1.0], [1.6, 1.0], [0.5, 1.0]])
    sidewalk, terrain = 8, 9
    out = resolve_frame(track, ground, world, decided, predicted, field, Rules(far_radius=0.0), GROUND_CLASS,
                        (GroundRegion(square, sidewalk),))
    assert out.class_[[7, 8]].tolist() == [sidewalk, sidewalk]
    assert (out.source[[7, 8]] == SOURCE["region"]).all() and (out.confidence[[7, 8]] == 1.0).all()
    plain = resolve_frame(track, ground, world, decided, predicted, field, Rules(far_radius=0.0), GROUND_CLASS)
    keep = ~ground
    assert np.array_equal(out.class_[keep], plain.class_[keep]) and np.array_equal(out.source[keep], plain.source[keep])
    # a later region wins where it overlaps an earlier one; a region elsewhere changes nothing
    strip = np.array([[1.3, -1.0], [2.0, -1.0], [2.0, 1.0], [1.3, 1.0]])
    far = np.array([[50.0, 50.0], [51.0, 50.0], [51.0, 51.0]])
    out = resolve_frame(track, ground, world, decided, predicted, field, Rules(far_radius=0.0), GROUND_CLASS,
                        (GroundRegion(square, sidewalk), GroundRegion(strip, terrain), GroundRegion(far, CAR)))
    assert out.class_[[7, 8]].tolist() == [sidewalk, terrain]


def test_region_with_heights_labels_every_point_of_its_prism_a_decided_one_s_too():
    from pipeline.propagation import GroundRegion

    track, ground, world, decided, predicted = _frame()
    field = _field(world, track, decided)
    square = np.array([[0.5, -1.0], [1.6, -1.0], [1.6, 1.0], [0.5, 1.0]])  # car point 1, loose 4, ground 7 and 8
    hedge = GroundRegion(square, BUSH, (0.98, 1.5))  # ground point 7 (z 0.95) lies under it
    out = resolve_frame(track, ground, world, decided, predicted, field, Rules(far_radius=0.0), GROUND_CLASS, (hedge,))
    assert out.class_[[1, 4, 8]].tolist() == [BUSH] * 3 and (out.source[[1, 4, 8]] == SOURCE["region"]).all()
    plain = resolve_frame(track, ground, world, decided, predicted, field, Rules(far_radius=0.0), GROUND_CLASS)
    rest = np.setdiff1d(np.arange(len(track)), [1, 4, 8])
    assert np.array_equal(out.class_[rest], plain.class_[rest])  # the car's other point, the far ones, point 7
    # a newer region of ground points is drawn over it where they overlap: the ground points only
    out = resolve_frame(track, ground, world, decided, predicted, field, Rules(far_radius=0.0), GROUND_CLASS,
                        (hedge, GroundRegion(square, 9)))
    assert out.class_[[1, 4, 7, 8]].tolist() == [BUSH, BUSH, 9, 9]


def test_a_lassoed_object_reaches_the_points_just_above_it_and_a_prism_or_a_ground_class_does_not():
    from pipeline.propagation import GroundRegion

    other = 6
    world = np.array([[10.0, 0, 1.0], [12.0, 0, 1.0], [10.2, 0, 0.8], [10.25, 0, 1.4]])
    track = np.array([2, 2, 0, 0])  # track 2 predicted bush; a ground point (low leaves); a loose point
    ground = np.array([False, False, True, False])
    predicted = TrackClasses.of([(2, BUSH, SOURCE["predicted"], 0.8)])
    none = TrackClasses.of([])
    lasso = np.array([[10.1, -0.5], [10.3, -0.5], [10.3, 0.5], [10.1, 0.5]])
    rules = Rules(far_radius=5.0)

    def resolve(*regions, rules=rules):
        return resolve_frame(track, ground, world, none, predicted, None, rules, GROUND_CLASS, regions)

    out = resolve(GroundRegion(lasso, other, None, True))
    assert out.class_.tolist() == [other, BUSH, other, BUSH]  # 0.22 m from the lassoed point; 1.8 m; the lasso's; the loose
    assert out.source.tolist() == [SOURCE["propagated"], SOURCE["predicted"], SOURCE["region"], SOURCE["predicted"]]
    # the loose point (0.6 m from the lassoed one) takes its frame's nearest label that no region gave
    for plain in (resolve(GroundRegion(lasso, other, None, False)),  # a ground class
                  resolve(GroundRegion(lasso, other, (0.7, 0.9), True)),  # a prism
                  resolve(GroundRegion(lasso, other, None, True), rules=Rules(far_radius=5.0, region_radius=0.0))):
        assert plain.class_[[0, 1, 3]].tolist() == [BUSH, BUSH, BUSH]
        assert plain.source[0] == SOURCE["predicted"]


def test_a_lasso_in_a_frame_s_view_labels_every_point_of_that_frame_it_holds_and_none_behind_or_elsewhere():
    from pipeline.propagation import GroundRegion

    track, ground, world, decided, predicted = _frame()
    field = _field(world, track, decided)
    # a camera at (-5, 0, 1) looking along +x (right: -y, up: z) sees every point on its axis; its
    # near and far planes at 4.5 and 6.5 m hold the car (x = 0, 1), the loose point at 1.2 and
    # both ground points, and not the far ones (x = 3, 10, 11, 11.25)
    near, far = 4.5, 6.5
    a, b = (far + near) / (far - near), -2 * far * near / (far - near)
    view = np.array([[0, -1, 0, 0], [0, 0, 1, -1], [a, 0, 0, 5 * a + b], [1, 0, 0, 5]], np.float64)
    square = np.array([[-0.5, -0.5], [0.5, -0.5], [0.5, 0.5], [-0.5, 0.5]])
    lasso = GroundRegion(square, BUSH, frame=3, view=view)
    assert lasso.labels(world, None, 3).tolist() == [True, True, False, False, True, False, False, True, True]
    assert not lasso.labels(world, None, 2).any() and not lasso.labels(world, None).any()
    out = resolve_frame(track, ground, world, decided, predicted, field, Rules(far_radius=0.0), GROUND_CLASS,
                        (lasso,), frame=3)
    assert out.class_[[0, 1, 4, 7, 8]].tolist() == [BUSH] * 5  # the reviewed car's points too
    assert (out.source[[0, 1, 4, 7, 8]] == SOURCE["region"]).all()
    plain = resolve_frame(track, ground, world, decided, predicted, field, Rules(far_radius=0.0), GROUND_CLASS)
    other = resolve_frame(track, ground, world, decided, predicted, field, Rules(far_radius=0.0), GROUND_CLASS,
                          (lasso,), frame=2)
    assert np.array_equal(other.class_, plain.class_) and np.array_equal(other.source, plain.source)
    assert np.array_equal(out.class_[[2, 3, 5, 6]], plain.class_[[2, 3, 5, 6]])
