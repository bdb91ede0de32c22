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


# The table as it was written in code before it became the `paper` label set: the derived names
# and lookup tables must equal these, so every existing caller sees the same values.
_OLD_SAMPLE_CLASSES = ("person", "car", "cyclist", "trunk", "bush", "building", "unknown")
_OLD_SEMANTICKITTI_IDS = {
    "person": (30, 254), "car": (10, 13, 18, 20, 252, 256, 257, 258, 259), "cyclist": (31, 32, 253, 255),
    "trunk": (71,), "bush": (70,), "building": (50,), "ground": (40, 44, 48, 49, 60, 72),
}
_OLD_WRITE_ID = {"person": 30, "car": 10, "cyclist": 31, "trunk": 71, "bush": 70, "building": 50,
                 "unknown": 80, "ground": 40}
_OLD_COLOURS = {"person": (255, 30, 30), "car": (100, 150, 245), "cyclist": (255, 200, 20),
                "trunk": (135, 60, 0), "bush": (0, 175, 0), "building": (200, 200, 200),
                "unknown": (150, 0, 255), "ground": (80, 80, 80)}


def test_classes_derived_names_equal_the_old_literals():
    assert classes.SAMPLE_CLASSES == _OLD_SAMPLE_CLASSES
    assert classes.NUM_SAMPLE_CLASSES == 7 and classes.GROUND == 7 and classes.UNLABELLED == 255
    assert classes.POINT_CLASSES == (*_OLD_SAMPLE_CLASSES, "ground")
    assert classes.CLASS_INDEX == {n: i for i, n in enumerate((*_OLD_SAMPLE_CLASSES, "ground"))}
    assert classes.SEMANTICKITTI_IDS == _OLD_SEMANTICKITTI_IDS
    assert classes.SEMANTICKITTI_UNLABELLED_IDS == (0, 1)
    assert classes.SEMANTICKITTI_WRITE_ID == _OLD_WRITE_ID
    assert classes.MOVING_IDS == {"car": 252, "cyclist": 253, "person": 254}
    assert classes.CLASS_COLOURS == _OLD_COLOURS


def test_classes_derived_lookup_tables_equal_the_old_construction():
    index = {n: i for i, n in enumerate((*_OLD_SAMPLE_CLASSES, "ground"))}
    to_ours = np.full(1 << 16, index["unknown"], np.uint8)
    to_ours[[0, 1]] = 255
    for name, ids in _OLD_SEMANTICKITTI_IDS.items():
        to_ours[list(ids)] = index[name]
    to_sk = np.zeros(256, np.uint16)
    for name, sk in _OLD_WRITE_ID.items():
        to_sk[index[name]] = sk
    colours = np.full((256, 3), 40, np.uint8)
    for name, rgb in _OLD_COLOURS.items():
        colours[index[name]] = rgb
    every_id = np.arange(1 << 16, dtype=np.uint32) | (np.uint32(3) << 16)
    np.testing.assert_array_equal(classes.to_ours(every_id), to_ours)
    np.testing.assert_array_equal(classes.to_semantickitti(np.arange(256)), to_sk)
    np.testing.assert_array_equal(classes.colour_table(), colours)
    assert classes.to_ours(every_id).dtype == np.uint8 and classes.to_semantickitti(np.arange(3)).dtype == np.uint16
