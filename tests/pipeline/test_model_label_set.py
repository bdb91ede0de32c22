"""A checkpoint names its label set; a model used with another label set is a clear error."""

from __future__ import annotations

import pytest
import torch

from pipeline.config import ModelConfig, SampleConfig
from pipeline.errors import LabelSetMismatch
from pipeline.label_sets import preset
from pipeline.model import check_label_set, get_model, load_checkpoint, save_checkpoint

SAMPLES = SampleConfig(size=16)


def _checkpoint(path, label_set: str):
    classes = preset(label_set).sample_class_names
    config = ModelConfig(width=4, max_width=8, depth=2, num_classes=len(classes))
    return save_checkpoint(path, get_model(config, SAMPLES), config, SAMPLES, classes=classes, label_set=label_set)


def test_model_label_set_checkpoint_names_its_label_set_and_classes(tmp_path):
    model, meta = load_checkpoint(_checkpoint(tmp_path / "sk.pt", "semantickitti"))
    assert meta.label_set == "semantickitti"
    assert meta.classes == preset("semantickitti").sample_class_names
    assert model.config.num_classes == len(preset("semantickitti").sample_classes)


def test_model_label_set_old_checkpoint_without_it_is_paper(tmp_path):
    path = _checkpoint(tmp_path / "old.pt", "paper")
    payload = torch.load(path, weights_only=True)
    del payload["label_set"]  # as checkpoints written before label sets hold
    torch.save(payload, path)
    _, meta = load_checkpoint(path)
    assert meta.label_set == "paper"
    check_label_set(meta, preset("paper"), path)


def test_model_label_set_other_set_raises_naming_both(tmp_path):
    path = _checkpoint(tmp_path / "sk.pt", "semantickitti")
    _, meta = load_checkpoint(path)
    with pytest.raises(LabelSetMismatch, match=r"sk.pt: the model was trained on label set 'semantickitti'.*not on 'paper'"):
        check_label_set(meta, preset("paper"), path)


def test_model_label_set_same_name_other_classes_raises(tmp_path):
    path = _checkpoint(tmp_path / "p.pt", "paper")
    _, meta = load_checkpoint(path)
    renamed = preset("nuscenes").model_copy(update={"name": "paper"})
    with pytest.raises(LabelSetMismatch):
        check_label_set(meta, renamed, path)


def test_model_label_set_predict_takes_a_model_of_any_set_with_that_set(tmp_path):
    path = _checkpoint(tmp_path / "sk.pt", "semantickitti")
    _, meta = load_checkpoint(path)
    check_label_set(meta, preset("semantickitti"), path)
    with pytest.raises(LabelSetMismatch):
        check_label_set(meta, preset("nuscenes"), path)
