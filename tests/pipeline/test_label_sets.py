from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from pipeline.errors import ConfigError
from pipeline.label_sets import (
    UNLABELLED,
    dump_label_set,
    from_semantickitti_yaml,
    load_label_set,
    preset,
    preset_names,
    read_label_set,
    validate_label_set,
)
from tests.pipeline.label_set_factory import SEMANTIC_KITTI_YAML, label_set_data, write_label_set


def test_label_sets_presets_are_paper_first_then_semantickitti_and_nuscenes():
    assert preset_names()[0] == "paper"
    assert set(preset_names()) >= {"paper", "semantickitti", "nuscenes"}


def test_label_sets_every_preset_loads_under_its_file_name():
    for name in preset_names():
        assert preset(name).name == name


def test_label_sets_semantickitti_preset_has_the_19_learning_map_classes_in_order():
    names = [c.name for c in preset("semantickitti").classes]
    assert names == ["car", "bicycle", "motorcycle", "truck", "other-vehicle", "person", "bicyclist",
                     "motorcyclist", "road", "parking", "sidewalk", "other-ground", "building", "fence",
                     "vegetation", "trunk", "terrain", "pole", "traffic-sign"]


def test_label_sets_semantickitti_preset_equals_the_import_of_semantic_kitti_yaml():
    imported = from_semantickitti_yaml(SEMANTIC_KITTI_YAML, name="semantickitti")
    shipped = preset("semantickitti")
    assert imported.classes == shipped.classes
    assert imported.unlabelled_ids == shipped.unlabelled_ids
    np.testing.assert_array_equal(imported.to_index_table(), shipped.to_index_table())


def test_label_sets_semantickitti_reads_the_learning_map():
    s = preset("semantickitti")
    got = s.to_index_table()[[10, 252, 13, 60, 52, 99, 0, 1, 81]]
    want = [s.index(n) for n in ("car", "car", "other-vehicle", "road")] + [UNLABELLED] * 4 + [
        s.index("traffic-sign")]
    assert got.tolist() == want


def test_label_sets_nuscenes_preset_has_the_16_lidarseg_classes():
    names = {c.name for c in preset("nuscenes").classes}
    assert names == {"barrier", "bicycle", "bus", "car", "construction_vehicle", "motorcycle", "pedestrian",
                     "traffic_cone", "trailer", "truck", "driveable_surface", "other_flat", "sidewalk",
                     "terrain", "manmade", "vegetation"}


@pytest.mark.parametrize("name", ["paper", "semantickitti", "nuscenes"])
def test_label_sets_written_ids_read_back_as_their_class(name):
    s = preset(name)
    every = np.arange(len(s.point_classes))
    np.testing.assert_array_equal(s.to_index_table()[s.to_semantickitti_table()[every]], every)


def test_label_sets_ground_classes_come_after_the_sample_classes():
    s = preset("semantickitti")
    ground = [s.index(c.name) for c in s.ground_classes]
    assert sorted(ground) == list(range(len(s.sample_classes), len(s.classes)))
    assert s.point_class_names[: len(s.sample_classes)] == s.sample_class_names


def test_label_sets_a_25_class_file_loads_by_path(tmp_path):
    path = write_label_set(tmp_path / "mine.yaml", label_set_data(25, n_ground=3))
    s = load_label_set(str(path))
    assert len(s.point_classes) == 25 and len(s.sample_classes) == 22
    assert s.to_index_table()[1024] == s.index("class-24")


def test_label_sets_dump_reads_back_equal(tmp_path):
    for name in preset_names():
        path = tmp_path / f"{name}.yaml"
        path.write_text(dump_label_set(preset(name)))
        assert read_label_set(path) == preset(name)


def test_label_sets_unknown_preset_names_the_presets():
    with pytest.raises(ConfigError, match="presets: paper"):
        load_label_set("kitti360")


def _error_of(tmp_path: Path, data: object) -> str:
    path = write_label_set(tmp_path / "bad.yaml", data)
    with pytest.raises(ConfigError) as exc:
        read_label_set(path)
    assert str(path) in str(exc.value)
    return str(exc.value)


def _with(data: dict, i: int, **fields: object) -> dict:
    data["classes"][i].update(fields)
    return data


@pytest.mark.parametrize(("change", "expected"), [
    (lambda d: _with(d, 1, colour=[0, 256, 0]), r"field classes\.1 \(class-01\)\.colour\.1: .*less than or equal to 255"),
    (lambda d: _with(d, 2, colour=[0, 0]), r"field classes\.2 \(class-02\)\.colour"),
    (lambda d: _with(d, 1, kind="blob"), r"field classes\.1 \(class-01\)\.kind"),
    (lambda d: _with(d, 0, colour=None, name="x"), r"field classes\.0 \(x\)\.colour"),
    (lambda d: _with(d, 3, name="Bad Name"), r"field classes\.3 \(Bad Name\)\.name"),
    (lambda d: _with(d, 1, shape="round"), r"field classes\.1 \(class-01\)\.shape: Extra inputs"),
    (lambda d: _with(d, 1, moving=5), r"field classes\.1 \(class-01\): moving: class-01's moving id 5"),
    (lambda d: _with(d, 2, key="F1"), r"field classes: key 'F1' is given to more than one class"),
    (lambda d: _with(d, 2, name="class-01"), r"field classes: name 'class-01'"),
    (lambda d: _with(d, 2, reads=[1002, 1001]), r"field classes: reads 1001"),
    (lambda d: _with(d, 2, writes=1001, reads=[1001]), r"field classes: writes 1001"),
    (lambda d: _with(d, 2, writes=7), r"field classes: class-02 writes 7 but does not read it back"),
    (lambda d: {**d, "classes": []}, r"field classes: .*at least 1"),
    (lambda d: {**d, "fallback": "nothing"}, r"field fallback: 'nothing' is not a class"),
    (lambda d: {**d, "unlabelled_ids": [1003]}, r"field unlabelled_ids: id 1003 is also read"),
    (lambda d: {**d, "unlabelled_ids": [70000]}, r"field unlabelled_ids\.0"),
    (lambda d: {k: v for k, v in d.items() if k != "name"}, r"field name: Field required"),
    (lambda d: ["not", "a", "mapping"], r"a label set is a mapping"),
])
def test_label_sets_an_invalid_file_names_the_file_and_the_field(tmp_path, change, expected):
    import re

    message = _error_of(tmp_path, change(label_set_data(5)))
    assert re.search(expected, message), message


def test_label_sets_unparsable_yaml_names_the_file(tmp_path):
    path = tmp_path / "broken.yaml"
    path.write_text("name: [unclosed\n")
    with pytest.raises(ConfigError, match="broken.yaml: cannot read label set"):
        read_label_set(path)


def test_label_sets_too_many_classes_for_the_uint8_index(tmp_path):
    data = label_set_data(UNLABELLED + 1)
    assert "at most 255" in _error_of(tmp_path, data)


def test_label_sets_validate_accepts_a_mapping_without_a_file():
    assert len(validate_label_set(label_set_data(3), "inline").classes) == 3


def test_label_sets_import_names_a_missing_learning_map(tmp_path):
    path = tmp_path / "sk.yaml"
    path.write_text("labels: {0: unlabeled}\ncolor_map: {0: [0, 0, 0]}\n")
    with pytest.raises(ConfigError, match=r"sk.yaml: field learning_map: missing"):
        from_semantickitti_yaml(path)


def test_label_sets_import_names_a_class_without_colour(tmp_path):
    path = tmp_path / "sk.yaml"
    path.write_text("labels: {0: unlabeled, 10: car}\ncolor_map: {0: [0, 0, 0]}\nlearning_map: {0: 0, 10: 1}\n")
    with pytest.raises(ConfigError, match=r"sk.yaml: field color_map: no entry for id 10"):
        from_semantickitti_yaml(path)


def test_label_sets_the_documented_example_is_valid():
    import re

    import yaml

    doc = (Path(__file__).resolve().parents[2] / "docs" / "label_sets.md").read_text()
    example = re.search(r"```yaml\n(.*?)```", doc, re.S).group(1)
    s = validate_label_set(yaml.safe_load(example), "docs/label_sets.md")
    assert s.point_class_names == ("person", "vehicle", "other", "road", "grass")
    assert s.to_index_table()[81] == s.index("other") and s.to_index_table()[1] == UNLABELLED
