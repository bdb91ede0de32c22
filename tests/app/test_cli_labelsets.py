from __future__ import annotations

import yaml
from typer.testing import CliRunner

from app.cli import app as cli
from pipeline.label_sets import preset, read_label_set
from tests.pipeline.label_set_factory import SEMANTIC_KITTI_YAML, label_set_data, write_label_set


def test_cli_labelset_list_shows_the_three_presets():
    result = CliRunner().invoke(cli, ["labelset", "list"])
    assert result.exit_code == 0
    names = [line.split()[0] for line in result.output.splitlines()]
    assert names[0] == "paper" and {"paper", "semantickitti", "nuscenes"} <= set(names)


def test_cli_labelset_show_lists_every_class_in_index_order():
    result = CliRunner().invoke(cli, ["labelset", "show", "paper"])
    assert result.exit_code == 0
    rows = [line.split() for line in result.output.splitlines()[2:-1]]
    assert [r[1] for r in rows] == list(preset("paper").point_class_names)
    assert rows[-1][:6] == ["7", "ground", "8", "stuff", "yes", "40"]


def test_cli_labelset_show_unknown_name_exits_2_naming_the_presets():
    result = CliRunner().invoke(cli, ["labelset", "show", "kitti360"])
    assert result.exit_code == 2
    assert "unknown label set 'kitti360'" in result.output and "paper" in result.output


def test_cli_labelset_check_accepts_a_valid_25_class_file(tmp_path):
    path = write_label_set(tmp_path / "mine.yaml", label_set_data(25, n_ground=4))
    result = CliRunner().invoke(cli, ["labelset", "check", str(path)])
    assert result.exit_code == 0, result.output
    assert "valid: 25 classes (21 sample, 4 ground)" in result.output


def test_cli_labelset_check_names_the_field_of_an_invalid_file(tmp_path):
    data = label_set_data(25)
    data["classes"][12]["colour"] = [0, 300, 0]
    path = write_label_set(tmp_path / "bad.yaml", data)
    result = CliRunner().invoke(cli, ["labelset", "check", str(path)])
    assert result.exit_code == 2
    assert f"{path}: field classes.12 (class-12).colour.1" in result.output


def test_cli_labelset_check_missing_file_exits_2(tmp_path):
    result = CliRunner().invoke(cli, ["labelset", "check", str(tmp_path / "none.yaml")])
    assert result.exit_code == 2 and "none.yaml: cannot read label set" in result.output


def test_cli_labelset_import_writes_a_file_that_checks(tmp_path):
    out = tmp_path / "sk.yaml"
    result = CliRunner().invoke(cli, ["labelset", "import", str(SEMANTIC_KITTI_YAML), "--name", "sk", "--out", str(out)])
    assert result.exit_code == 0, result.output
    assert read_label_set(out).classes == preset("semantickitti").classes
    assert yaml.safe_load(out.read_text())["name"] == "sk"
