from __future__ import annotations

import numpy as np
import pytest
import torch

from pipeline.classes import SAMPLE_CLASSES
from pipeline.config import ModelConfig, SampleConfig, TrainingConfig
from pipeline.errors import DataError
from pipeline.model import (
    NetConfig,
    build_model,
    embed,
    get_model,
    load_checkpoint,
    predict,
    save_checkpoint,
    to_input,
)

TINY = ModelConfig(width=4, max_width=8, depth=2, dropout=0.5)


def _net(size: int = 16, channels: int = 4) -> NetConfig:
    return NetConfig.from_configs(TINY, SampleConfig(size=size, foreground_channel=channels == 4))


def _canvases(n: int, size: int = 16, channels: int = 4, seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 256, (n, channels, size, size), dtype=np.uint8)


@pytest.mark.parametrize("size", [64, 256])
def test_model_logits_have_k_columns_for_paper_and_default_sizes(size):
    torch.manual_seed(0)
    model = build_model(_net(size)).eval()
    with torch.no_grad():
        logits = model(to_input(torch.from_numpy(_canvases(2, size))))
    assert logits.shape == (2, 7)


def test_model_features_have_last_block_width():
    model = build_model(_net())
    assert embed(model, _canvases(3)).shape == (3, 8)


def test_model_three_channel_config_without_foreground_mask():
    model = build_model(_net(channels=3))
    assert predict(model, _canvases(2, channels=3)).shape == (2, 7)


def test_model_size_not_divisible_by_pooling_is_rejected():
    with pytest.raises(ValueError, match="divisible"):
        build_model(NetConfig(size=18, depth=2))


def test_model_predict_gives_probabilities_deterministically():
    torch.manual_seed(0)
    model = build_model(_net()).train()
    x = _canvases(5)
    p1, p2 = predict(model, x, batch=2), predict(model, x, batch=5)
    assert p1.dtype == np.float32 and p1.shape == (5, 7)
    np.testing.assert_allclose(p1.sum(axis=1), 1.0, rtol=1e-5)
    np.testing.assert_allclose(p1, p2, rtol=1e-5, atol=1e-6)  # eval mode: no dropout, running BN stats
    assert model.training  # mode restored


def test_model_predict_wrong_channel_count_raises_data_error():
    with pytest.raises(DataError, match="samples"):
        predict(build_model(_net()), _canvases(2, channels=3))


def test_model_predict_empty_input_gives_empty_output():
    assert predict(build_model(_net()), _canvases(0)).shape == (0, 7)


def test_model_checkpoint_round_trip_gives_identical_outputs(tmp_path):
    torch.manual_seed(0)
    model = build_model(_net())
    with torch.no_grad():  # move BN running stats away from their defaults
        model.train()(to_input(torch.from_numpy(_canvases(8))))
    sample_cfg = SampleConfig(size=16)
    path = save_checkpoint(tmp_path / "m.pt", model, TINY, sample_cfg, {"mean_f": 42.0}, TrainingConfig(epochs=3))
    loaded, meta = load_checkpoint(path, "cpu")
    x = _canvases(4, seed=1)
    np.testing.assert_array_equal(predict(model, x), predict(loaded, x))
    assert meta.net == model.config
    assert meta.model_config == TINY and meta.sample_config == sample_cfg
    assert meta.training_config == TrainingConfig(epochs=3)
    assert meta.classes == SAMPLE_CLASSES
    assert meta.metrics == {"mean_f": 42.0}
    assert not loaded.training


def test_model_load_checkpoint_missing_file_names_it(tmp_path):
    with pytest.raises(DataError, match="nope.pt"):
        load_checkpoint(tmp_path / "nope.pt")


def test_model_load_checkpoint_corrupt_file_raises_data_error(tmp_path):
    bad = tmp_path / "bad.pt"
    bad.write_bytes(b"not a checkpoint")
    with pytest.raises(DataError, match="bad.pt"):
        load_checkpoint(bad)


def test_model_load_checkpoint_foreign_dict_raises_data_error(tmp_path):
    path = tmp_path / "foreign.pt"
    torch.save({"state_dict": {}}, path)
    with pytest.raises(DataError, match="not a tracklabel"):
        load_checkpoint(path)


def test_model_get_model_follows_sample_config():
    model = get_model(TINY, SampleConfig(size=32, foreground_channel=False))
    assert model.config.in_channels == 3 and model.config.size == 32 and model.config.stem_stride == 2


def test_model_checkpoint_written_with_removed_training_options_still_loads(tmp_path):
    model = build_model(_net())
    path = save_checkpoint(tmp_path / "m.pt", model, TINY, SampleConfig(size=16), {}, TrainingConfig(epochs=3))
    payload = torch.load(path, weights_only=True)
    payload["training_config"] |= {"gamma_rampup": 0.0, "component_power": None}  # as older checkpoints hold
    torch.save(payload, path)
    _, meta = load_checkpoint(path, "cpu")
    assert meta.training_config == TrainingConfig(epochs=3)


def test_model_checkpoint_from_before_intensity_normalisation_reads_raw_intensity(tmp_path):
    # written before per-sensor normalisation: no `intensity` in its sample config, no input
    # statistics; its model knows raw intensities only
    model = build_model(_net())
    stats = {"channels": {"intensity": {"p1": 0.1, "p5": 0.2, "p50": 0.5, "p95": 0.8, "p99": 0.9}}}
    path = save_checkpoint(tmp_path / "m.pt", model, TINY, SampleConfig(size=16), {}, input_stats=stats)
    _, meta = load_checkpoint(path, "cpu")
    assert meta.sample_config.intensity == "sensor" and meta.input_stats == stats
    payload = torch.load(path, weights_only=True)
    del payload["sample_config"]["intensity"], payload["input_stats"]
    torch.save(payload, path)
    _, meta = load_checkpoint(path, "cpu")
    assert meta.sample_config.intensity == "raw" and meta.input_stats == {}
