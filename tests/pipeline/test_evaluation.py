from __future__ import annotations

import numpy as np

from pipeline.evaluation import FrameTruth, evaluate_frames, evaluate_stitches, object_keys

CAR, BUSH = 10, 70  # SemanticKITTI ids


def _frame(track: list[int], sem: list[int], inst: list[int], dist: float = 10.0) -> FrameTruth:
    n = len(track)
    key, ik = object_keys(np.array(sem), np.array(inst))
    pts = np.zeros((n, 3), np.float32)
    pts[:, 0] = dist
    return FrameTruth(np.array(track, np.uint32), key, ik, pts)


def test_evaluation_object_keys_stuff_by_class_things_by_instance():
    key, inst = object_keys(np.array([CAR, CAR, BUSH, BUSH]), np.array([1, 2, 3, 4]))
    assert key[0] != key[1]  # two cars are two objects
    assert key[2] == key[3]  # bushes are keyed by class
    assert inst[2] != inst[3]


def test_evaluation_purity_and_precision_by_hand():
    # frame 0: track 1 = 8 car#1 points + 2 bush points; track 2 = 5 car#2 points
    f0 = _frame([1] * 10 + [2] * 5, [CAR] * 8 + [BUSH] * 2 + [CAR] * 5, [1] * 8 + [9] * 2 + [2] * 5)
    # frame 1: track 1 = car#1 (right), track 2 now dominated by car#1 as well (a wrong link)
    f1 = _frame([1] * 6 + [2] * 4, [CAR] * 10, [1] * 10)
    res = evaluate_frames([f0, f1], links=[(0, 1), (0, 2)])
    o = res["overall"]
    assert o["segments"] == 4
    assert np.isclose(o["purity"], (8 + 5 + 6 + 4) / (10 + 5 + 6 + 4))
    assert np.isclose(o["pure_fraction"], 3 / 4)  # only the 8/10 segment is under 0.95
    assert o["links"] == 2 and np.isclose(o["association_precision"], 0.5)
    assert res["per_class"]["car"]["segments"] == 4


def test_evaluation_recall_counts_presences_with_30_points():
    big = [1] * 40 + [0] * 5  # car#1 with 40 points in the track, 5 unsegmented
    f0 = _frame(big + [0] * 10, [CAR] * 45 + [BUSH] * 10, [1] * 45 + [3] * 10)
    f1 = _frame(big + [0] * 10, [CAR] * 45 + [BUSH] * 10, [1] * 45 + [3] * 10)
    linked = evaluate_frames([f0, f1], links=[(0, 1)])["overall"]
    unlinked = evaluate_frames([f0, f1], links=[])["overall"]
    # presences: car#1 (45 pts) only; the bush has 10 points < 30
    assert linked["presences"] == unlinked["presences"] == 1
    assert linked["association_recall"] == 1.0 and unlinked["association_recall"] == 0.0


def test_evaluation_per_range_bins():
    f0 = _frame([1] * 10, [CAR] * 10, [1] * 10, dist=40.0)
    res = evaluate_frames([f0], links=[])
    assert res["per_range"]["30-50"]["segments"] == 1 and res["per_range"]["0-15"]["segments"] == 0


def test_evaluation_stitches_by_dominant_object_of_each_track():
    # track 1: bush#3 over two frames; track 2: bush#3 (a piece of it); track 3: bush#4 (another
    # bush: same class, other object); track 4: car#1 whose frame-0 segment held 2 bush points
    f0 = _frame([1] * 6 + [2] * 3 + [3] * 4 + [4] * 7, [BUSH] * 13 + [BUSH] * 2 + [CAR] * 5,
                [3] * 9 + [4] * 4 + [3] * 2 + [1] * 5)
    f1 = _frame([1] * 5 + [4] * 5, [BUSH] * 5 + [CAR] * 5, [3] * 5 + [1] * 5)
    res = evaluate_stitches([f0, f1], np.array([[1, 2], [1, 3], [1, 4], [2, 99]]))
    assert res["stitches"] == 3  # track 99 does not exist
    assert res["same_object"] == 1 / 3 and res["same_class"] == 2 / 3
    assert evaluate_stitches([f0, f1], np.zeros((0, 2), np.int64))["same_object"] is None
