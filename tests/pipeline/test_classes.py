from __future__ import annotations

import numpy as np

from pipeline import classes


def test_classes_semantickitti_table_maps_each_listed_id():
    for name, ids in classes.SEMANTICKITTI_IDS.items():
        got = classes.to_ours(np.array(ids))
        assert (got == classes.CLASS_INDEX[name]).all(), name


def test_classes_unlabelled_and_outlier_map_to_unlabelled():
    assert (classes.to_ours(np.array([0, 1])) == classes.UNLABELLED).all()


def test_classes_other_ids_map_to_unknown():
    assert (classes.to_ours(np.array([80, 81, 99, 51, 52])) == classes.CLASS_INDEX["unknown"]).all()


def test_classes_round_trip_through_semantickitti():
    ours = np.arange(8)
    assert (classes.to_ours(classes.to_semantickitti(ours)) == ours).all()


def test_classes_instance_bits_are_ignored():
    label = (np.uint32(7) << 16) | np.uint32(252)
    assert classes.to_ours(np.array([label]))[0] == classes.CLASS_INDEX["car"]
