from __future__ import annotations

import pytest
import yaml

from pipeline.config import PipelineConfig, load_config
from pipeline.errors import ConfigError


def test_config_yaml_overrides_only_named_fields(tmp_path):
    p = tmp_path / "c.yaml"
    p.write_text(yaml.safe_dump({"samples": {"size": 256}}))
    cfg = load_config(p)
    assert cfg.samples.size == 256
    assert cfg.samples.sigma == PipelineConfig().samples.sigma


def test_config_bad_field_names_the_field(tmp_path):
    p = tmp_path / "c.yaml"
    p.write_text(yaml.safe_dump({"training": {"gamma": 3.0}}))
    with pytest.raises(ConfigError, match="training.gamma"):
        load_config(p)


def test_config_dump_round_trips(tmp_path):
    cfg = PipelineConfig().override({"association": {"min_score": 0.5}})
    cfg.dump(tmp_path / "used.yaml")
    assert load_config(tmp_path / "used.yaml") == cfg
