from __future__ import annotations

import numpy as np
import pytest

from pipeline.anchors import propose
from pipeline.config import ModelConfig, SampleConfig, TrainingConfig
from pipeline.errors import ConfigError, DataError
from pipeline.finetune import finetune, finetune_data
from pipeline.model import embed as embed_features
from pipeline.model import load_checkpoint, predict
from pipeline.training import LabelledSamples, TrainingData, evaluate, train

K = 7
SIZE = 16
SAMPLES = SampleConfig(size=SIZE)
TINY = ModelConfig(width=16, max_width=32, depth=2, dropout=0.0)


def scene(n_tracks: int, per_track: int, shift: int, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A tiny simulated scene: tracks of `per_track` noisy views of one object each.

    Class k is a 4x4 blob at its own place on the canvas; a new scene (`shift` > 0) moves the
    blobs of classes 0..3 by `shift` pixels and changes their range channel, the way a new
    place changes how objects look. Returns (samples (M, 4, S, S) uint8, labels (M,), tracks (M,)).
    """
    rng = np.random.default_rng(seed)
    y_track = rng.permutation(np.arange(n_tracks) % K)
    y = np.repeat(y_track, per_track)
    tracks = np.repeat(np.arange(1, n_tracks + 1), per_track)
    n = len(y)
    x = rng.integers(0, 40, (n, 4, SIZE, SIZE))
    x[:, 3] = 0
    moved = y < 4
    r0 = 2 + 4 * (y % 3) + rng.integers(-1, 2, n) + np.where(moved, shift, 0)
    c0 = 2 + 5 * (y // 3) + rng.integers(-1, 2, n) + np.where(moved, shift // 2, 0)
    rows = np.arange(SIZE)[None, :, None]
    cols = np.arange(SIZE)[None, None, :]
    blob = (rows >= r0[:, None, None]) & (rows < r0[:, None, None] + 4)
    blob = blob & (cols >= c0[:, None, None]) & (cols < c0[:, None, None] + 4)
    x[:, 0][blob] = 200
    value = 100 + 20 * y + np.where(moved & (shift > 0), 60, 0)
    x[:, 1] = np.where(blob, value[:, None, None], x[:, 1])
    x[:, 3][blob] = 255
    return np.clip(x, 0, 255).astype(np.uint8), y.astype(np.int64), tracks


def consecutive_pairs(tracks: np.ndarray) -> np.ndarray:
    same = tracks[1:] == tracks[:-1]
    i = np.flatnonzero(same)
    return np.stack([i, i + 1], 1)


@pytest.fixture(scope="module")
def pretrained(tmp_path_factory: pytest.TempPathFactory):
    x, y, _ = scene(140, 5, shift=0, seed=0)
    cfg = TrainingConfig(epochs=6, steps_per_epoch=None, batch_labelled=32, lr=3e-3, lr_schedule="constant",
                         augment=False, balanced_labels=False, device="cpu", threads=1, seed=0)
    out = tmp_path_factory.mktemp("pre")
    res = train(TrainingData.build(x, np.arange(len(y)), y), cfg, TINY, SAMPLES, checkpoint_dir=out)
    assert res.checkpoint is not None
    return res.checkpoint


def test_finetune_on_new_scene_beats_pretrained(pretrained, tmp_path):
    x, y, tracks = scene(70, 6, shift=3, seed=1)  # the new scene: 420 samples in 70 tracks
    model, meta = load_checkpoint(pretrained)
    before = evaluate(model, LabelledSamples(x, y))
    # the default strategy proposes 2 tracks per class; a simulated operator answers from truth
    probs = predict(model, x)
    props = propose(probs, counts=np.full(K, 2), features=embed_features(model, x), tracks=tracks)
    labelled = np.isin(tracks, props.track)  # each confirmed track labels its samples
    pairs = consecutive_pairs(tracks)
    data = finetune_data(x, np.flatnonzero(labelled), y[labelled], pairs, constraints="verified")
    cfg = TrainingConfig(device="cpu", threads=1, seed=0).finetuning().model_copy(update={"epochs": 6, "steps_per_epoch": 15})
    res = finetune(pretrained, data, cfg, checkpoint_dir=tmp_path)
    after = evaluate(res.model, LabelledSamples(x, y))
    assert before.mean_f < 75.0  # the scene shift hurts the pretrained model
    assert after.mean_f > before.mean_f + 10.0, (before.mean_f, after.mean_f)
    # the checkpoint describes itself and names its parent
    assert res.checkpoint is not None
    _, m2 = load_checkpoint(res.checkpoint)
    assert m2.metrics["kind"] == "finetune" and m2.metrics["parent"] == str(pretrained)
    assert sum(m2.metrics["anchors_per_class"].values()) == int(labelled.sum())
    assert m2.metrics["pairs"] == len(pairs)


def test_finetune_data_constraint_modes():
    x = np.zeros((6, 4, SIZE, SIZE), np.uint8)
    pairs = np.array([[0, 1], [1, 2], [3, 4], [4, 5]])
    score = np.array([0.9, 0.0, 0.5, np.nan], np.float32)
    verified = np.array([True, True, False, False])
    d = finetune_data(x, [0, 0, 3], [1, 2, 4], pairs, score, verified, "verified")
    assert d.labelled.tolist() == [0, 3] and d.labels.tolist() == [1, 4]  # duplicate anchor dropped
    assert d.pairs.tolist() == [[0, 1], [1, 2]] and d.pair_weights.tolist() == [1.0, 1.0]
    d = finetune_data(x, [0], [1], pairs, score, verified, "automatic")
    assert d.pairs.tolist() == [[0, 1], [3, 4]]  # zero and NaN scores carry no weight
    assert np.allclose(d.pair_weights, [0.9, 0.5])
    d = finetune_data(x, [0], [1], pairs, score, verified, "none")
    assert len(d.pairs) == 0
    with pytest.raises(ConfigError, match="constraints must be"):
        finetune_data(x, [0], [1], pairs, constraints="all")


def test_finetune_refuses_constraints_only(pretrained):
    x = np.zeros((4, 4, SIZE, SIZE), np.uint8)
    data = finetune_data(x, [], [], np.array([[0, 1]]))
    with pytest.raises(DataError, match="at least one confirmed anchor"):
        finetune(pretrained, data, TrainingConfig(device="cpu", epochs=1).finetuning())


def test_finetuning_config_changes_only_the_step_budget_batch_and_label_draws():
    base = TrainingConfig(lr=0.01, seed=3)
    cfg = base.finetuning()
    assert (cfg.lr, cfg.seed, cfg.augment, cfg.transitive_pairs, cfg.lr_schedule) == (0.01, 3, True, True, "cosine")
    assert (cfg.epochs * cfg.steps_per_epoch, cfg.batch_labelled, cfg.pairs_per_label) == (800, 16, 2)
    assert not cfg.closure_labels and not cfg.balanced_labels  # anchors are balanced by repetition
    changed = {k for k in TrainingConfig.model_fields if getattr(cfg, k) != getattr(base, k)}
    assert changed == {"steps_per_epoch", "batch_labelled", "pairs_per_label", "closure_labels",
                       "balanced_labels"}


def test_balance_classes_repeats_rare_classes():
    from pipeline.finetune import balance_classes

    idx, y = balance_classes(np.array([10, 11, 12, 13, 20]), np.array([4, 4, 4, 4, 0]))
    assert np.bincount(y, minlength=5).tolist() == [4, 0, 0, 0, 4]
    assert sorted(idx[y == 0].tolist()) == [20] * 4 and sorted(idx[y == 4].tolist()) == [10, 11, 12, 13]
    x = np.zeros((30, 4, SIZE, SIZE), np.uint8)
    d = finetune_data(x, [10, 11, 12, 13, 20], [4, 4, 4, 4, 0], balance=True)
    assert len(d.labelled) == 8 and len(np.unique(d.labelled)) == 5
