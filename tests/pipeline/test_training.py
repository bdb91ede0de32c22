from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from pipeline.config import ModelConfig, SampleConfig, TrainingConfig
from pipeline.errors import ConfigError, DataError
from pipeline.model import NetConfig, build_model, load_checkpoint, predict, to_input
from pipeline.training import (
    EpochRecord,
    LabelledSamples,
    TrainingData,
    augment_batch,
    learning_rate,
    semi_supervised_loss,
    split_by_group,
    train,
)
from pipeline.training.loop import _select
from pipeline.training.sampling import _TrackPartners

K = 7
SIZE = 16
SAMPLES = SampleConfig(size=SIZE)
TINY = ModelConfig(width=16, max_width=32, depth=2, dropout=0.0)


def blobs(n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Separable 4-channel SIZE x SIZE canvases: class k has a 4x4 blob at its own place.

    Returns (canvases (n, 4, S, S) uint8, labels (n,) int64).
    """
    rng = np.random.default_rng(seed)
    y = rng.integers(0, K, n)
    x = rng.integers(0, 40, (n, 4, SIZE, SIZE))
    x[:, 3] = 0
    r0 = 2 + 4 * (y % 3) + rng.integers(-1, 2, n)  # (n,) blob top row
    c0 = 2 + 5 * (y // 3) + rng.integers(-1, 2, n)  # (n,) blob left column
    rows = np.arange(SIZE)[None, :, None]
    cols = np.arange(SIZE)[None, None, :]
    blob = (rows >= r0[:, None, None]) & (rows < r0[:, None, None] + 4)
    blob = blob & (cols >= c0[:, None, None]) & (cols < c0[:, None, None] + 4)  # (n, S, S)
    x[:, 0][blob] = 200
    x[:, 1] = np.where(blob, 100 + 20 * y[:, None, None], x[:, 1])
    x[:, 3][blob] = 255
    return x.astype(np.uint8), y.astype(np.int64)


def same_class_pairs(y: np.ndarray, seed: int) -> np.ndarray:
    """(P, 2) must-link pairs: each sample with a random sample of its own class."""
    rng = np.random.default_rng(seed)
    parts = [np.stack([idx, rng.permutation(idx)], 1) for idx in (np.flatnonzero(y == k) for k in range(K))]
    return np.concatenate(parts)


def _cfg(**kw) -> TrainingConfig:
    # the paper's plain training (no extension) unless a test turns one on
    base = {"epochs": 8, "steps_per_epoch": None, "batch_labelled": 32, "pairs_per_label": 5, "lr": 3e-3,
            "lr_schedule": "constant", "augment": False, "balanced_labels": False, "transitive_pairs": False,
            "closure_labels": False, "device": "cpu"}
    return TrainingConfig(**(base | kw))


# ---------------------------------------------------------------- loss


def test_loss_matches_hand_computed_value():
    ln = math.log
    # labelled: logits (0, ln 3) -> P = (1/4, 3/4), label 1; logits (0, 0) -> P = (1/2, 1/2), label 0
    logits_l = torch.tensor([[0.0, ln(3)], [0.0, 0.0]], dtype=torch.float64)
    labels = torch.tensor([1, 0])
    # pairs: ((1/4, 3/4), (1/2, 1/2)) agree 1/8 + 3/8 = 1/2; ((1/4, 3/4), (1/4, 3/4)) agree 1/16 + 9/16
    logits_i = torch.tensor([[0.0, ln(3)], [0.0, ln(3)]], dtype=torch.float64)
    logits_j = torch.tensor([[0.0, 0.0], [0.0, ln(3)]], dtype=torch.float64)
    parts = semi_supervised_loss(logits_l, labels, logits_i, logits_j, gamma=0.5)
    l_l = (-ln(3 / 4) - ln(1 / 2)) / 2  # 0.4904146...
    l_c = 0.5 / 2 * ((1 - 1 / 2) + (1 - 10 / 16))  # 0.21875
    assert parts.labelled.item() == pytest.approx(l_l, abs=1e-12)
    assert parts.constraint.item() == pytest.approx(0.21875, abs=1e-12)
    assert parts.total.item() == pytest.approx(l_l + l_c, abs=1e-12)
    assert parts.balance.item() == 0.0


def test_loss_pair_weights_scale_each_pair_term():
    ln = math.log
    logits_i = torch.tensor([[0.0, ln(3)], [0.0, ln(3)]], dtype=torch.float64)
    logits_j = torch.tensor([[0.0, 0.0], [0.0, ln(3)]], dtype=torch.float64)
    empty = torch.zeros((0, 2), dtype=torch.float64)
    w = torch.tensor([1.0, 0.5], dtype=torch.float64)
    parts = semi_supervised_loss(empty, torch.zeros(0, dtype=torch.long), logits_i, logits_j, 1.0, w)
    assert parts.constraint.item() == pytest.approx((0.5 + 0.5 * 0.375) / 2, abs=1e-12)


def test_loss_squared_difference_is_the_papers_term_less_the_gini_impurity():
    ln = math.log
    logits_i = torch.tensor([[0.0, ln(3)], [0.0, ln(3)]], dtype=torch.float64)  # (1/4, 3/4) twice
    logits_j = torch.tensor([[0.0, 0.0], [0.0, ln(3)]], dtype=torch.float64)  # (1/2, 1/2), (1/4, 3/4)
    empty = torch.zeros((0, 2), dtype=torch.float64)
    no_labels = torch.zeros(0, dtype=torch.long)
    sq = semi_supervised_loss(empty, no_labels, logits_i, logits_j, 1.0, constraint_loss="squared")
    # 1/2 |P_i - P_j|^2: 1/2 (1/16 + 1/16) and 0; a pair that agrees costs nothing however unsure
    assert sq.constraint.item() == pytest.approx((1 / 16 + 0.0) / 2, abs=1e-12)
    paper = semi_supervised_loss(empty, no_labels, logits_i, logits_j, 1.0)
    gini = ((1 - 10 / 16) + (1 - 1 / 2)) / 2 / 2 + (1 - 10 / 16) / 2  # mean over pairs of both sides' mean
    assert paper.constraint.item() == pytest.approx(sq.constraint.item() + gini, abs=1e-12)


def test_loss_labels_only_is_cross_entropy():
    logits = torch.tensor([[2.0, 0.0, -1.0]])
    empty = torch.zeros((0, 3))
    parts = semi_supervised_loss(logits, torch.tensor([0]), empty, empty, gamma=1.0, balance_weight=1.0)
    assert parts.constraint.item() == 0.0 and parts.balance.item() == 0.0
    assert parts.total.item() == pytest.approx(-math.log(math.exp(2) / (math.exp(2) + 1 + math.exp(-1))), rel=1e-6)


def test_loss_constraints_only_has_no_labelled_term():
    logits_i = torch.tensor([[0.0, 0.0]])
    parts = semi_supervised_loss(torch.zeros((0, 2)), torch.zeros(0, dtype=torch.long), logits_i, logits_i, 1.0)
    assert parts.labelled.item() == 0.0
    assert parts.total.item() == pytest.approx(0.5)  # 1 - (1/4 + 1/4)


def test_loss_empty_batch_raises():
    empty = torch.zeros((0, 2))
    with pytest.raises(ValueError, match="labelled samples or pairs"):
        semi_supervised_loss(empty, torch.zeros(0, dtype=torch.long), empty, empty, 1.0)


def test_loss_constraint_term_is_zero_for_identical_one_hot_predictions():
    one_hot = torch.tensor([[60.0, 0.0, 0.0], [0.0, 0.0, 60.0]], dtype=torch.float64)
    parts = semi_supervised_loss(torch.zeros((0, 3)), torch.zeros(0, dtype=torch.long), one_hot, one_hot, 1.0)
    assert parts.constraint.item() == pytest.approx(0.0, abs=1e-20)


def test_loss_balance_term_zero_for_uniform_marginal_and_positive_for_one_class():
    empty = torch.zeros((0, 2), dtype=torch.float64)
    no_labels = torch.zeros(0, dtype=torch.long)
    mixed = torch.tensor([[30.0, 0.0], [0.0, 30.0]], dtype=torch.float64)  # classes 0 and 1: marginal (1/2, 1/2)
    collapsed = torch.tensor([[30.0, 0.0], [30.0, 0.0]], dtype=torch.float64)
    b_mixed = semi_supervised_loss(empty, no_labels, mixed, mixed, 1.0, balance_weight=1.0).balance
    b_collapsed = semi_supervised_loss(empty, no_labels, collapsed, collapsed, 1.0, balance_weight=1.0).balance
    assert b_mixed.item() == pytest.approx(0.0, abs=1e-9)
    assert b_collapsed.item() == pytest.approx(math.log(2), abs=1e-9)


def test_loss_gradients_flow_through_both_sides_of_a_pair():
    torch.manual_seed(0)
    model = build_model(NetConfig.from_configs(TINY, SAMPLES))
    x, _ = blobs(4, seed=0)
    xi = to_input(torch.from_numpy(x[:2])).requires_grad_(True)  # (2, C, S, S)
    xj = to_input(torch.from_numpy(x[2:])).requires_grad_(True)
    logits = model(torch.cat([xi, xj]))  # one siamese forward, shared weights: (4, K)
    parts = semi_supervised_loss(logits[:0], torch.zeros(0, dtype=torch.long), logits[:2], logits[2:], 1.0)
    parts.total.backward()
    assert xi.grad.abs().sum() > 0 and xj.grad.abs().sum() > 0
    assert model.head.weight.grad.abs().sum() > 0


# ---------------------------------------------------------------- helpers


def test_augment_batch_flips_and_shifts_whole_canvases():
    x = torch.zeros((64, 1, 9, 9))
    x[:, 0, 4, 2] = 1.0  # one lit pixel at row 4, column 2
    out = augment_batch(x, max_shift=1, generator=torch.Generator().manual_seed(0))
    assert out.shape == x.shape
    lit = out[:, 0].nonzero()  # (B, 3): batch, row, col
    assert len(lit) == 64  # the pixel never leaves the canvas with shift 1
    assert set(lit[:, 1].tolist()) == {3, 4, 5}
    assert set(lit[:, 2].tolist()) == {1, 2, 3, 5, 6, 7}  # column 2 or its mirror 6, +-1


def test_split_by_group_keeps_tracks_whole_and_each_class_fraction():
    # class 0: 10 tracks of 3 samples, class 1: 20 tracks of 2, class 2: one track of 4
    tracks = np.concatenate([np.repeat(np.arange(10), 3), np.repeat(np.arange(10, 30), 2), np.full(4, 99)])
    labels = np.repeat([0, 1, 2], [30, 40, 4])
    tr, va = split_by_group(labels, tracks, 0.3, seed=0)
    assert sorted(np.concatenate([tr, va]).tolist()) == list(range(len(labels)))
    assert not set(tracks[tr].tolist()) & set(tracks[va].tolist())  # no track on both sides
    assert [len(np.unique(tracks[va][labels[va] == k])) for k in range(3)] == [3, 6, 0]  # a lone track stays in training
    again = split_by_group(labels, tracks, 0.3, seed=0)
    assert np.array_equal(again[1], va) and not np.array_equal(split_by_group(labels, tracks, 0.3, seed=1)[1], va)


def _rec(epoch: int, loss: float, val_f: float) -> EpochRecord:
    return EpochRecord(epoch, loss, loss, 0.0, 0.0, val_f, 1.0, 1.0)


def test_select_best_val_f_among_epochs_below_loss_threshold():
    hist = [_rec(0, 0.9, 95.0), _rec(1, 0.4, 70.0), _rec(2, 0.3, 80.0), _rec(3, 0.2, 75.0)]
    assert _select(hist, 0.5) == (2, "val_f_below_threshold")


def test_select_falls_back_to_lowest_loss_when_none_below_threshold():
    hist = [_rec(0, 0.9, 95.0), _rec(1, 0.6, 70.0), _rec(2, 0.7, 80.0)]
    assert _select(hist, 0.5) == (1, "lowest_loss")


# ---------------------------------------------------------------- training


@pytest.fixture(scope="module")
def blob_data() -> tuple[np.ndarray, np.ndarray, LabelledSamples]:
    x, y = blobs(420, seed=0)
    xv, yv = blobs(140, seed=1)
    return x, y, LabelledSamples(xv, yv)


def test_train_separable_blobs_reach_high_accuracy(blob_data, tmp_path):
    x, y, val = blob_data
    res = train(TrainingData.build(x, np.arange(len(x)), y), _cfg(), TINY, SAMPLES, val=val, checkpoint_dir=tmp_path)
    acc = (predict(res.model, val.samples).argmax(1) == val.labels).mean()
    assert acc >= 0.9, (acc, res.metrics["val_f"])
    assert res.val_report is not None and res.val_report.mean_f == pytest.approx(res.history[res.selected_epoch].val_f)
    loaded, meta = load_checkpoint(res.checkpoint)
    np.testing.assert_array_equal(predict(loaded, val.samples[:8]), predict(res.model, val.samples[:8]))
    assert meta.metrics["selected_epoch"] == res.selected_epoch
    assert (tmp_path / "last.pt").is_file()
    # the checkpoint describes its training canvases, channel by channel, for predict's warnings
    assert meta.input_stats == res.input_stats and meta.input_stats["canvases"] == len(x)
    assert set(meta.input_stats["channels"]) <= {"height", "range", "intensity", "foreground"}


def test_train_semi_supervised_with_augmentation_runs_both_terms(blob_data):
    x, y, val = blob_data
    labelled = np.flatnonzero(np.arange(len(y)) % 10 == 0)
    data = TrainingData.build(x, labelled, y[labelled], same_class_pairs(y, 0))
    res = train(data, _cfg(epochs=2, steps_per_epoch=3, batch_labelled=8, augment=True), TINY, SAMPLES, val=val)
    assert len(res.history) == 2
    assert all(r.loss_labelled > 0 and r.loss_constraint > 0 for r in res.history)


def test_train_same_seed_gives_same_history(blob_data):
    x, y, _ = blob_data
    data = TrainingData.build(x[:64], np.arange(64), y[:64])
    cfg = _cfg(epochs=2, batch_labelled=16, augment=True, seed=3)
    a = train(data, cfg, TINY, SAMPLES)
    b = train(data, cfg, TINY, SAMPLES)
    assert [r.loss for r in a.history] == [r.loss for r in b.history]


def test_train_stop_hook_cancels_and_keeps_a_model(blob_data):
    x, y, _ = blob_data
    calls = []

    def stop() -> bool:
        calls.append(1)
        return len(calls) > 2

    res = train(TrainingData.build(x, np.arange(len(x)), y), _cfg(epochs=5), TINY, SAMPLES, stop=stop)
    assert res.cancelled
    assert len(res.history) == 1 and res.selected_epoch == 0


def test_train_progress_callback_reports_each_epoch(blob_data):
    x, y, val = blob_data
    seen = []
    data = TrainingData.build(x[:96], np.arange(96), y[:96])
    train(data, _cfg(epochs=2, batch_labelled=16), TINY, SAMPLES, val=val, report=seen.append)
    ends = [p for p in seen if p.epoch_done]
    assert [p.epoch for p in ends] == [0, 1]
    assert ends[-1].fraction == 1.0 and ends[-1].val_f is not None
    assert any(not p.epoch_done for p in seen)  # intermediate step reports too


def test_train_sample_shape_mismatch_raises_config_error(blob_data):
    x, y, _ = blob_data
    with pytest.raises(ConfigError, match="sample config"):
        train(TrainingData.build(x, np.arange(len(x)), y), _cfg(), TINY, SampleConfig(size=64))


def test_train_without_labels_or_pairs_raises_data_error(blob_data):
    x, _, _ = blob_data
    with pytest.raises(DataError, match="neither"):
        train(TrainingData.build(x), _cfg(), TINY, SAMPLES)


def test_training_data_pair_index_out_of_range_raises():
    x, _ = blobs(4, seed=0)
    with pytest.raises(DataError, match="pairs"):
        TrainingData.build(x, pairs=np.array([[0, 4]]))


@pytest.fixture(scope="module")
def pretrained(blob_data):
    """A weak classifier from 3 labels per class: confident, but far from the truth."""
    x, y, _ = blob_data
    few = np.concatenate([np.flatnonzero(y == k)[:3] for k in range(K)])
    return train(TrainingData.build(x, few, y[few]), _cfg(epochs=30, batch_labelled=21), TINY, SAMPLES).model


def _constraints_only(blob_data, pretrained, balance_weight: float) -> np.ndarray:
    x, y, val = blob_data
    data = TrainingData.build(x, pairs=same_class_pairs(y, 0))
    cfg = _cfg(epochs=12, batch_labelled=16, balance_weight=balance_weight, loss_threshold=-1.0)
    res = train(data, cfg, TINY, SAMPLES, init_model=pretrained)
    assert all(r.loss_labelled == 0.0 for r in res.history)  # M = 0: the degenerate case
    return np.bincount(predict(res.model, val.samples).argmax(1), minlength=K)


def test_train_constraints_only_balance_term_keeps_classes_apart(blob_data, pretrained):
    """The paper's unsupervised fine-tuning (Fig. 12): L_c alone pulls predictions onto few classes;
    the marginal-entropy term keeps them spread over the 7 classes (measured: 2-3 vs 7 classes used)."""
    without = _constraints_only(blob_data, pretrained, 0.0)
    with_balance = _constraints_only(blob_data, pretrained, 1.0)
    assert (with_balance > 0).sum() >= 6, with_balance
    assert (without > 0).sum() < (with_balance > 0).sum(), (without, with_balance)
    assert without.max() > with_balance.max()  # the largest predicted class is bigger without it


def test_train_threads_option_applies_during_the_run_only(blob_data):
    x, y, _ = blob_data
    original = torch.get_num_threads()
    torch.set_num_threads(2)
    during = []
    data = TrainingData.build(x[:32], np.arange(32), y[:32])
    try:
        train(data, _cfg(epochs=1, threads=1), TINY, SAMPLES, report=lambda _p: during.append(torch.get_num_threads()))
        after = torch.get_num_threads()
    finally:
        torch.set_num_threads(original)
    assert set(during) == {1}
    assert after == 2


def test_balanced_labels_draw_classes_uniformly():
    from pipeline.training.sampling import _BalancedCycler, _Cycler

    labels = np.array([0] * 900 + [1] * 90 + [2] * 10)
    rng = np.random.default_rng(0)
    drawn = labels[_BalancedCycler(labels, rng).take(3000)]
    share = np.bincount(drawn, minlength=3) / 3000
    assert np.all(np.abs(share - 1 / 3) < 0.05)
    plain = labels[_Cycler(len(labels), np.random.default_rng(0)).take(3000)]
    assert np.bincount(plain, minlength=3)[2] == 30  # uniform over samples: the rare class 1 %


def test_train_with_balanced_labels_runs():
    x, y = blobs(120, 3)
    res = train(TrainingData.build(x, np.arange(len(y)), y), _cfg(epochs=1, balanced_labels=True), TINY, SAMPLES)
    assert len(res.history) == 1 and math.isfinite(res.history[0].loss)


def test_learning_rate_cosine_runs_from_lr_to_zero():
    cfg = _cfg(lr=1e-3, lr_schedule="cosine")
    assert learning_rate(cfg, 0, 100) == pytest.approx(1e-3)
    assert learning_rate(cfg, 50, 100) == pytest.approx(5e-4)
    assert learning_rate(cfg, 100, 100) == pytest.approx(0.0, abs=1e-12)
    assert learning_rate(_cfg(lr=1e-3), 70, 100) == 1e-3  # constant: the paper's


def test_track_partners_draw_any_other_member_of_the_track():
    # two tracks as chains of consecutive pairs: 0-1-2-3 and 5-6; sample 4 is in no pair
    pairs = np.array([[0, 1], [1, 2], [2, 3], [5, 6]])
    tp = _TrackPartners(pairs, 8, np.random.default_rng(0))
    left = np.repeat([0, 3, 5, 6], 300)
    right = tp.draw(left)
    for a in (0, 3):
        got = set(right[left == a].tolist())
        assert got == {0, 1, 2, 3} - {a}  # every other member, the far end included, never itself
    assert set(right[left == 5].tolist()) == {6} and set(right[left == 6].tolist()) == {5}


def test_component_draws_weigh_each_component_alike():
    from pipeline.training.sampling import _ComponentDraw

    # component {0..9}: 9 pairs; component {20, 21}: 1 pair
    pairs = np.array([[i, i + 1] for i in range(9)] + [[20, 21]])
    draw = _ComponentDraw(pairs, 30, np.random.default_rng(0))
    got = draw.take(4000)
    assert abs(np.mean(got == 9) - 0.5) < 0.03  # the lone pair of the small component: half the draws
    assert set(np.unique(got[got != 9]).tolist()) == set(range(9))  # the big one's pairs alike


def test_train_with_component_draws_and_squared_difference_runs(blob_data):
    x, y, _ = blob_data
    labelled = np.flatnonzero(np.arange(len(y)) % 10 == 0)
    data = TrainingData.build(x, labelled, y[labelled], same_class_pairs(y, 0))
    cfg = _cfg(epochs=2, steps_per_epoch=3, batch_labelled=8, transitive_pairs=True, pair_draw="component",
               constraint_loss="squared")
    res = train(data, cfg, TINY, SAMPLES)
    assert len(res.history) == 2 and all(math.isfinite(r.loss) and r.loss_constraint >= 0 for r in res.history)


def test_train_with_transitive_pairs_and_cosine_lr_runs(blob_data):
    x, y, _ = blob_data
    labelled = np.flatnonzero(np.arange(len(y)) % 10 == 0)
    data = TrainingData.build(x, labelled, y[labelled], same_class_pairs(y, 0))
    cfg = _cfg(epochs=2, steps_per_epoch=3, batch_labelled=8, transitive_pairs=True, lr_schedule="cosine")
    res = train(data, cfg, TINY, SAMPLES)
    assert len(res.history) == 2 and all(math.isfinite(r.loss) for r in res.history)


def test_closure_labels_spread_over_components_and_skip_disagreeing_ones():
    from pipeline.training import closure_labels

    # components {0,1,2} (labelled 1 as class 2), {3,4} (3 as 4), {5,6,7} (5 as 1, 7 as 3: they
    # disagree), 8 alone (labelled 0), 9 alone (unlabelled)
    pairs = np.array([[0, 1], [1, 2], [3, 4], [5, 6], [6, 7]])
    idx, lab, conflicts = closure_labels(np.array([1, 3, 5, 7, 8]), np.array([2, 4, 1, 3, 0]), pairs, 10)
    assert idx.tolist() == [0, 1, 2, 3, 4, 5, 7, 8]
    assert lab.tolist() == [2, 2, 2, 4, 4, 1, 3, 0]
    assert conflicts == 1
    idx, lab, conflicts = closure_labels(np.array([1]), np.array([2]), np.zeros((0, 2), np.int64), 10)
    assert idx.tolist() == [1] and lab.tolist() == [2] and conflicts == 0


def test_train_with_closure_labels_runs(blob_data):
    x, y, val = blob_data
    labelled = np.flatnonzero(np.arange(len(y)) % 50 == 0)
    data = TrainingData.build(x, labelled, y[labelled], same_class_pairs(y, 0))
    res = train(data, _cfg(epochs=2, steps_per_epoch=3, batch_labelled=8, closure_labels=True), TINY, SAMPLES, val=val)
    assert len(res.history) == 2 and all(r.loss_labelled > 0 for r in res.history)


def test_annotation_draw_gives_each_annotation_its_own_weight_spread_over_its_component():
    from pipeline.training.sampling import _AnnotationDraw, _closure

    # component {0..9} holds annotation 0 (class 1); {10, 11} holds annotation 10 (class 1);
    # {20, 21} holds 20 (class 2) and 21 (class 3): they disagree and spread to nothing
    pairs = np.array([[i, i + 1] for i in range(9)] + [[10, 11], [20, 21]])
    annotated, labels = np.array([0, 10, 20, 21]), np.array([1, 1, 2, 3])
    idx, lab, conflicts, group = _closure(annotated, labels, pairs, 30)
    assert conflicts == 1 and idx.tolist() == [*range(12), 20, 21]
    draw = _AnnotationDraw(np.searchsorted(idx, annotated), labels, group, False, np.random.default_rng(0))
    got = idx[draw.take(8000)]
    # each annotation a quarter of the draws, whatever its component's size
    assert (got < 10).mean() == pytest.approx(0.25, abs=0.02)
    assert np.isin(got, [10, 11]).mean() == pytest.approx(0.25, abs=0.02)
    assert (got == 20).mean() == pytest.approx(0.25, abs=0.02) and (got == 21).mean() == pytest.approx(0.25, abs=0.02)
    counts = np.bincount(got, minlength=30)[:10]
    assert counts.min() > 0.6 * counts.max()  # uniform inside the component
    # drawing the closure's samples alike instead gives the 10-sample component 10 / 14 of them
    # (closure_draw="sample"); balanced: class-uniform over the annotations' classes
    bal = lab[_AnnotationDraw(np.searchsorted(idx, annotated), labels, group, True,
                              np.random.default_rng(0)).take(9000)]
    assert np.bincount(bal, minlength=4)[1:] / 9000 == pytest.approx([1 / 3] * 3, abs=0.02)


def test_train_with_closure_drawn_per_annotation_runs(blob_data):
    x, y, val = blob_data
    labelled = np.flatnonzero(np.arange(len(y)) % 50 == 0)
    data = TrainingData.build(x, labelled, y[labelled], same_class_pairs(y, 0))
    cfg = _cfg(epochs=2, steps_per_epoch=3, batch_labelled=8, closure_labels=True, closure_draw="annotation",
               balanced_labels=True)
    res = train(data, cfg, TINY, SAMPLES, val=val)
    assert len(res.history) == 2 and all(r.loss_labelled > 0 for r in res.history)
    with pytest.raises(ValueError):
        _cfg(closure_draw="track")


def test_erase_rectangles_zero_one_rectangle_in_the_given_share_of_canvases():
    from pipeline.training import erase_rectangles

    x = torch.ones(400, 2, 32, 32)
    out = erase_rectangles(x, 0.5, torch.Generator().manual_seed(0))
    zero = out == 0  # (B, C, S, S)
    hit = zero.flatten(1).any(1)
    assert 0.4 < hit.float().mean().item() < 0.6
    assert torch.equal(zero[:, 0], zero[:, 1])  # every channel of a pixel alike
    for m in zero[hit, 0][:20]:  # one axis-aligned rectangle, a tenth to half the side each way
        rows, cols = m.any(1).nonzero().flatten(), m.any(0).nonzero().flatten()
        assert m.sum() == len(rows) * len(cols)
        assert 3 <= len(rows) <= 17 and 3 <= len(cols) <= 17
    assert torch.equal(out[~hit], x[~hit])
