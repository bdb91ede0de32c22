"""The simulated operator, ground truth of segments, and the experiment data preparation."""

from __future__ import annotations

import dataclasses

import numpy as np

from pipeline.links import sample_pairs
from research.experiments.data import (
    SceneSamples,
    confirm_stitches,
    operator_review,
    prepare_scene,
    route_part,
    segment_truth,
)


def test_operator_accepts_clean_tracks_truncates_at_first_wrong_link_and_skips_unknown_pairs():
    # track 1: objects A A B A A -> the first two kept; track 2 starts on an unlabelled segment ->
    # discarded; track 3 is unknown: labelled but no constraints; track 4: second sample impure.
    track = np.array([1, 1, 1, 1, 1, 2, 2, 3, 3, 3, 4, 4])
    frame = np.array([0, 1, 2, 3, 4, 0, 1, 5, 6, 7, 2, 3])
    cls = np.array([1, 1, 1, 1, 1, 255, 1, 6, 6, 6, 4, 4], np.int16)
    obj = np.array([10, 10, 11, 10, 10, 5, 5, 7, 7, 7, 8, 8])
    pur = np.array([1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 0.9, 0.3], np.float32)
    perm = np.random.default_rng(0).permutation(len(track))  # order of samples does not matter
    label, pairs = operator_review(track[perm], frame[perm], cls[perm], obj[perm], pur[perm],
                                   sample_pairs(track[perm], frame[perm]))
    assert label[np.argsort(perm)].tolist() == [1, 1, -1, -1, -1, -1, -1, 6, 6, 6, 4, -1]
    got = {tuple(sorted((int(perm[a]), int(perm[b])))) for a, b in pairs}
    assert got == {(0, 1)}


def test_sample_pairs_link_consecutive_samples_of_each_track():
    track = np.array([3, 3, 3, 5, 5])
    frame = np.array([2, 0, 1, 4, 6])  # track 5 has no sample at frame 5: linked over it, as ingest does
    pairs = sample_pairs(track, frame)
    assert pairs.tolist() == [[1, 2], [2, 0], [3, 4]]


def test_segment_truth_majority_object_and_purity():
    seg = np.array([0, 0, 0, 1, 1, -1, 2])
    sem = np.array([10, 10, 30, 40, 40, 40, 70])
    inst = np.array([1, 1, 2, 0, 0, 0, 3])
    cls, key, pur = segment_truth(seg, 4, sem, inst)
    assert cls.tolist() == [1, 7, 4, 255]
    assert key[0] == (1 << 32) | 1 and key[3] == -1
    np.testing.assert_allclose(pur, [2 / 3, 1, 1, 0])


def test_route_part_splits_by_distance():
    assert route_part(np.array([0.0, 0.29, 0.3, 0.59, 0.6, 1.0])).tolist() == [0, 0, 1, 1, 2, 2]


def test_prepare_scene_runs_the_pipeline_and_caches(tmp_path):
    scene = prepare_scene(tmp_path, seed=2, frames=4, size=32)
    assert isinstance(scene, SceneSamples) and len(scene) > 50
    assert scene.samples.shape[1:] == (4, 32, 32)
    assert len(scene.labelled) > 0 and len(scene.auto_pairs) >= len(scene.verified_pairs) > 0
    lab = scene.label[scene.labelled]
    assert np.array_equal(lab, scene.gt_class[scene.labelled])  # the operator labels with the truth
    assert scene.progress.min() == 0.0 and scene.progress.max() == 1.0
    s = scene.summary()
    assert s["labels"] == len(scene.labelled) and 0.5 < s["auto_pair_precision"] <= 1.0
    again = prepare_scene(tmp_path, seed=2, frames=4, size=32)  # from the cache
    assert np.array_equal(again.samples, scene.samples) and not list(tmp_path.glob("seq_*"))


def test_prepare_scene_caches_each_segmentation_apart(tmp_path):
    from pipeline.config import PipelineConfig

    plain = prepare_scene(tmp_path, seed=2, frames=3, size=32)
    unmerged = {"merge_pixels": 0, "bridge_horizontal": 0, "bridge_vertical": 0, "occluder_pixels": 0}
    pieces = prepare_scene(tmp_path, seed=2, frames=3, size=32,
                           config=PipelineConfig().override({"segmentation": unmerged}))
    assert len(list(tmp_path.glob("scene_*.npz"))) == 2  # the other segmentation did not reuse the cached scene
    # without merges and bridges objects fall apart: more samples and tracks in the same frames
    assert len(pieces) > len(plain) and len(np.unique(pieces.track)) > len(np.unique(plain.track))


def _toy_scene(n_tracks: int = 40, length: int = 5) -> SceneSamples:
    rng = np.random.default_rng(0)
    m = n_tracks * length
    track = np.repeat(np.arange(1, n_tracks + 1), length)
    frame = np.tile(np.arange(length), n_tracks) + np.repeat(np.arange(n_tracks), length)
    cls = np.repeat(np.arange(n_tracks) % 7, length).astype(np.int16)
    obj = track.astype(np.int64)
    auto = sample_pairs(track, frame)
    label, verified = operator_review(track, frame, cls, obj, np.ones(m, np.float32), auto)
    return SceneSamples(
        samples=rng.integers(0, 255, (m, 4, 8, 8), dtype=np.uint8), frame=frame.astype(np.int32),
        segment=np.zeros(m, np.int32), track=track, link_score=np.ones(m, np.float32), gt_class=cls,
        gt_object=obj, gt_purity=np.ones(m, np.float32), progress=(frame / frame.max()).astype(np.float32),
        label=label, verified_pairs=verified, auto_pairs=auto, auto_scores=np.full(len(auto), 0.8, np.float32),
    )


def test_paper_split_by_track_and_settings_grow_constraints():
    from research.experiments.paper import PaperConfig, setting_data, split_scene

    scene = _toy_scene()
    split = split_scene(scene, PaperConfig(labels_per_class=2))
    assert not set(scene.track[split.train_labelled]) & set(scene.track[split.val_labelled])  # no track on both sides
    assert np.bincount(scene.label[split.min_labelled], minlength=7).tolist() == [2] * 7
    assert set(split.min_labelled) <= set(split.train_labelled)
    sizes = []
    for name in ("constraint30", "constraint60", "constraint100"):
        lab, pairs, w = setting_data(name, scene, split)
        assert np.array_equal(lab, split.min_labelled) and (w == 1).all()
        assert not np.isin(scene.track[pairs[:, 0]], split.val_tracks).any()  # no validation track leaks in
        sizes.append(len(pairs))
    assert 0 < sizes[0] < sizes[1] < sizes[2]
    lab, pairs, w = setting_data("constraint100_auto", scene, split)
    assert len(pairs) >= sizes[2] and np.allclose(w, 0.8)
    lab, pairs, _ = setting_data("baseline_max", scene, split)
    assert np.array_equal(lab, split.train_labelled) and len(pairs) == 0


def test_paper_split_by_object_keeps_every_object_on_one_side():
    from research.experiments.paper import PaperConfig, setting_data, split_scene

    scene = _toy_scene(n_tracks=84, length=4)
    scene.gt_object[:] = (scene.track - 1) // 21 * 7 + (scene.track - 1) % 7  # 3 tracks per object, of one class
    split = split_scene(scene, PaperConfig(labels_per_class=2))
    train_obj, val_obj = set(scene.gt_object[split.train_labelled]), set(scene.gt_object[split.val_labelled])
    assert train_obj and val_obj and not train_obj & val_obj  # no object on both sides
    assert val_obj == set(split.val_objects.tolist())
    # a split by track would have put an object's tracks on both sides
    assert len(np.unique(scene.track[split.val_labelled])) == 3 * len(val_obj)
    # a wrong automatic link from a training object into a validation object is not trained on
    a = split.train_labelled[0]
    v = np.flatnonzero(np.isin(scene.gt_object, split.val_objects) & ~np.isin(scene.track, split.val_tracks))
    v = v[0] if len(v) else split.val_labelled[0]
    scene = dataclasses.replace(scene, auto_pairs=np.concatenate([scene.auto_pairs, [[a, v]]]),
                                auto_scores=np.concatenate([scene.auto_scores, [0.9]]).astype(np.float32))
    _, pairs, _ = setting_data("constraint100_auto", scene, split)
    assert not np.isin(scene.gt_object[pairs], split.val_objects).any()


def test_evaluation_set_scores_every_sample_of_a_sample_class_by_its_majority():
    from research.experiments.data import evaluation_set

    scene = _toy_scene(n_tracks=14, length=3)
    gt = scene.gt_class.copy()
    gt[0], gt[1] = 7, 255  # ground and unlabelled majorities are not scored
    purity = scene.gt_purity.copy()
    purity[3] = 0.2  # impure: the operator leaves it out, the evaluation scores its majority class
    label = scene.label.copy()
    label[[3, 4, 5]] = -1  # and a truncated tail
    scene = dataclasses.replace(scene, gt_class=gt, gt_purity=purity, label=label)
    idx, truth = evaluation_set(scene)
    assert idx.tolist() == list(range(2, len(scene)))  # every other sample, labelled by the operator or not
    assert np.array_equal(truth, gt[2:].astype(np.int64))


def test_label_seed_redraws_the_few_labels_but_keeps_split_and_default():
    from research.experiments.paper import PaperConfig, split_scene

    scene = _toy_scene(n_tracks=70, length=5)
    base = split_scene(scene, PaperConfig(labels_per_class=2))
    same = split_scene(scene, PaperConfig(labels_per_class=2, label_seed=None))
    assert np.array_equal(base.min_labelled, same.min_labelled)  # None keeps the default draw
    draws = [split_scene(scene, PaperConfig(labels_per_class=2, label_seed=k)) for k in (1, 2)]
    for d in draws:
        assert np.array_equal(d.train_labelled, base.train_labelled) and np.array_equal(d.val_tracks, base.val_tracks)
        assert np.bincount(scene.label[d.min_labelled], minlength=7).tolist() == [2] * 7
        assert set(d.min_labelled) <= set(d.train_labelled)
    assert not np.array_equal(draws[0].min_labelled, draws[1].min_labelled)
    assert not np.array_equal(draws[0].min_labelled, base.min_labelled)


def test_oracle_objects_label_every_view_of_the_labelled_objects_only():
    from research.experiments.paper import PaperConfig, oracle_object_labels, setting_data, split_scene

    scene = _toy_scene(n_tracks=40, length=9)
    scene.gt_object[:] = (scene.track - 1) // 2  # each object spans two tracks
    split = split_scene(scene, PaperConfig(labels_per_class=1))
    lab = oracle_object_labels(scene, split, per_object=4)
    assert set(lab) <= set(split.train_labelled)
    assert set(scene.gt_object[lab]) == set(scene.gt_object[split.min_labelled])
    counts = np.unique(scene.gt_object[lab], return_counts=True)[1]
    assert counts.max() == 4  # capped per object
    for obj in set(scene.gt_object[lab]):  # spread over the object's frames: its first and last view
        views = split.train_labelled[scene.gt_object[split.train_labelled] == obj]
        mine = lab[scene.gt_object[lab] == obj]
        assert scene.frame[mine].min() == scene.frame[views].min() and scene.frame[mine].max() == scene.frame[views].max()
    got, pairs, _ = setting_data("oracle_objects20", scene, split)
    assert len(pairs) == 0 and len(got) > len(split.min_labelled)


def test_oracle_object_pairs_make_each_labelled_object_one_component():
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    from research.experiments.paper import PaperConfig, oracle_object_pairs, setting_data, split_scene

    scene = _toy_scene(n_tracks=40, length=6)
    scene.gt_object[:] = (scene.track - 1) // 2  # each object spans two tracks
    split = split_scene(scene, PaperConfig(labels_per_class=1))
    pairs = oracle_object_pairs(scene, split)
    assert set(pairs.ravel()) <= set(split.train_labelled)
    assert (scene.gt_object[pairs[:, 0]] == scene.gt_object[pairs[:, 1]]).all()  # never across objects
    assert not (scene.label[pairs.ravel()] == 6).any()  # no unknown, as for the verified constraints
    _, comp = connected_components(coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(len(scene),) * 2))
    members = np.unique(pairs)
    for obj in np.unique(scene.gt_object[members]):  # one component per object, across its tracks
        assert len(np.unique(comp[members[scene.gt_object[members] == obj]])) == 1
    assert len(np.unique(scene.track[pairs.ravel()])) > len(np.unique(scene.gt_object[pairs.ravel()]))
    lab, got, w = setting_data("oracle_object_constraints", scene, split)
    assert np.array_equal(lab, split.min_labelled) and np.array_equal(got, pairs) and (w == 1).all()


def test_operator_confirms_stitches_of_one_object_only():
    # samples: 0-1 object 5 (two tracks), 2 object 6, 3 not kept (label -1), 4-5 unknown object 9
    label = np.array([1, 1, 1, -1, 6, 6], np.int16)
    obj = np.array([5, 5, 6, 5, 9, 9], np.int64)
    pairs = np.array([[1, 0], [2, 0], [3, 0], [5, 4]], np.int64)
    assert confirm_stitches(pairs, label, obj).tolist() == [[1, 0]]


def test_paper_constraints_add_confirmed_stitches_of_training_tracks_only():
    from research.experiments.paper import PaperConfig, setting_data, split_scene

    scene = _toy_scene()
    split = split_scene(scene, PaperConfig(labels_per_class=2))
    train_t = [t for t in np.unique(scene.track) if t not in split.val_tracks]
    # stitch two training tracks, and a training track to a validation track
    a, b = np.flatnonzero(scene.track == train_t[0])[-1], np.flatnonzero(scene.track == train_t[1])[0]
    v = np.flatnonzero(scene.track == split.val_tracks[0])[0]
    scene = dataclasses.replace(scene, stitched_pairs=np.array([[b, a], [v, a]], np.int64))
    _, base, _ = setting_data("constraint100_tracks_only", scene, split)
    _, stitched, _ = setting_data("constraint100", scene, split)
    added = {tuple(p) for p in stitched.tolist()} - {tuple(p) for p in base.tolist()}
    assert added == {(int(b), int(a))}


def test_paper_constraint_step_keeps_the_papers_canvases():
    from research.experiments.paper import PaperConfig

    cfg = PaperConfig()  # the paper's step: 16 labels + 80 pairs = 176 canvases
    assert cfg.equal_batch == 176
    assert cfg.constraint_batch == {"batch_labelled": 58, "pairs_per_label": 1}  # 174 canvases, never more
    assert cfg.batch_candidates("baseline_min") == (16, 176)  # labels only: both tried
    assert cfg.batch_candidates("constraint60") == (None,)
    assert cfg.setting_config("constraint60").batch_labelled == 58
    assert cfg.setting_config("constraint100_auto").pairs_per_label == 1
    paper = cfg.setting_config("constraint100_paper_batch")
    assert (paper.batch_labelled, paper.pairs_per_label) == (16, 5)
    only = cfg.setting_config("constraint100_closure_only")
    assert (only.batch_labelled, only.pairs_per_label) == (176, 0)


def test_paper_labels_via_constraints_are_drawn_per_annotation_unless_asked():
    from research.experiments.paper import ABLATIONS, PaperConfig

    cfg = PaperConfig()
    assert cfg.training_config().closure_draw == "annotation" and cfg.training_config().closure_labels
    assert "constraint100_sample_closure" in ABLATIONS
    assert cfg.setting_config("constraint100_sample_closure").closure_draw == "sample"
    assert not cfg.setting_config("constraint100_no_closure").closure_labels
    assert not cfg.setting_config("constraint100_auto").closure_labels  # unverified links spread no labels
    assert not cfg.setting_config("constraint100_paper_pairs").transitive_pairs


def test_paper_constraint100_trains_with_the_train_jobs_config():
    """One training path: the REST train job's default config is the experiment's constraint100."""
    from app.jobs.train import TrainParams, train_config
    from pipeline.config import TrainingConfig
    from research.experiments.finetune import FinetuneExperimentConfig
    from research.experiments.paper import PaperConfig

    job = train_config(TrainParams(sequence_ids=[1]))
    assert job == PaperConfig().setting_config("constraint100") == TrainingConfig()
    assert train_config(TrainParams(sequence_ids=[1], constraints="automatic")) == PaperConfig().setting_config(
        "constraint100_auto")
    # the fine-tuning experiment pretrains and fine-tunes with the jobs' configs too
    ft = FinetuneExperimentConfig(threads=0)
    assert ft.pretrain_config(with_pairs=True).model_copy(update={"steps_per_epoch": 200}) == TrainingConfig()
    from app.jobs.finetune import FinetuneParams, finetune_job_config

    assert ft.finetune_config(0) == finetune_job_config(FinetuneParams(sequence_id=1, model_id=1))


def test_paper_constraints_of_unknown_tracks_by_default_and_not_in_the_papers_ablation():
    from research.experiments.paper import PaperConfig, setting_data, split_scene, verified_constraints

    scene = _toy_scene()
    cfg = PaperConfig(labels_per_class=2)
    assert cfg.unknown_constraints
    split = split_scene(scene, cfg)
    _, paper, _ = setting_data("constraint100", scene, split, unknown_constraints=False)
    _, ours, _ = setting_data("constraint100", scene, split, unknown_constraints=True)
    _, ablation, _ = setting_data("constraint100_no_unknown", scene, split, unknown_constraints=True)
    assert not (scene.label[paper[:, 0]] == 6).any() and (scene.label[ours[:, 0]] == 6).any()
    assert np.array_equal(ablation, paper)
    known = scene.label[ours[:, 0]] != 6  # the rest is the paper's set
    assert {tuple(p) for p in ours[known].tolist()} == {tuple(p) for p in paper.tolist()}
    assert (scene.label[ours[:, 0]] == scene.label[ours[:, 1]]).all()  # inside one accepted track
    assert not np.isin(scene.track[ours], split.val_tracks).any()
    assert np.array_equal(verified_constraints(scene, False, stitches=False), scene.verified_pairs)
    assert len(verified_constraints(scene, True)) > len(scene.verified_pairs)  # D's adaptation takes the same set


def test_realistic_operator_misses_wrong_links_and_mislabels_tracks_at_the_given_rates():
    from research.experiments.data import realistic_review

    scene = _toy_scene(n_tracks=40, length=6)
    obj = scene.gt_object.copy()
    obj[np.arange(len(scene)) % 6 == 3] += 1000  # every track runs into another object at its 4th sample
    scene = dataclasses.replace(scene, gt_object=obj)
    careful, _ = operator_review(scene.track, scene.frame, scene.gt_class, obj, scene.gt_purity, scene.auto_pairs)
    same = realistic_review(scene, 0.0, 0.0, seed=0)
    assert np.array_equal(same.label, careful) and (same.label >= 0).sum() == 40 * 3
    blind = realistic_review(scene, 1.0, 0.0, seed=0)  # sees no wrong link: whole tracks labelled
    assert (blind.label >= 0).all() and np.array_equal(blind.label, scene.gt_class)
    crossing = blind.gt_object[blind.verified_pairs[:, 0]] != blind.gt_object[blind.verified_pairs[:, 1]]
    assert crossing.sum() > 0  # its missed links became verified constraints
    wrong = realistic_review(scene, 0.0, 1.0, seed=0)
    kept = wrong.label >= 0
    assert np.array_equal(kept, careful >= 0) and (wrong.label[kept] != scene.gt_class[kept]).all()


def test_concat_scenes_shifts_pairs_frames_and_tracks():
    from research.experiments.data import concat_scenes

    a, b = _toy_scene(n_tracks=10, length=3), _toy_scene(n_tracks=6, length=4)
    both = concat_scenes([a, b])
    assert len(both) == len(a) + len(b) and both.frame.dtype == a.frame.dtype
    n = len(a)
    assert np.array_equal(both.verified_pairs[len(a.verified_pairs):], b.verified_pairs + n)
    assert np.array_equal(both.samples[n:], b.samples)
    # each pair still joins two samples of one track, and no track or frame is shared by the scenes
    assert (both.track[both.verified_pairs[:, 0]] == both.track[both.verified_pairs[:, 1]]).all()
    assert not set(both.track[:n]) & set(both.track[n:]) and both.frame[n:].min() > both.frame[:n].max()
    assert concat_scenes([a]) is a


def test_default_model_split_keeps_each_object_and_its_pairs_on_one_side():
    from research.experiments.default_model import DefaultModelConfig, _split

    scene = _toy_scene(n_tracks=84, length=4)
    scene.gt_object[:] = (scene.track - 1) // 21 * 7 + (scene.track - 1) % 7  # 3 tracks per object
    data, val = _split(scene, DefaultModelConfig(val_max=10_000))
    train_obj = set(scene.gt_object[data.labelled].tolist())
    val_idx = np.flatnonzero(np.isin(scene.gt_object, sorted(set(scene.gt_object.tolist()) - train_obj)))
    assert train_obj and len(val) == len(val_idx) > 0  # every label of the other objects validates
    assert not np.isin(scene.gt_object[data.pairs], scene.gt_object[val_idx]).any()  # no pair reaches them


def test_split_by_object_ignores_a_realistic_operators_wrong_classes():
    from research.experiments.data import realistic_review, split_by_object

    scene = _toy_scene(n_tracks=840, length=4)
    scene.gt_object[:] = (scene.track - 1) // 21 * 7 + (scene.track - 1) % 7  # 3 tracks per object, one class
    careful = split_by_object(scene, 0.3, seed=0, per_class=2)
    noisy = split_by_object(realistic_review(scene, 0.0, 0.3, seed=0), 0.3, seed=0, per_class=2)
    # the same objects on each side: a track given a wrong class does not send its object to validation
    assert np.array_equal(noisy.val_objects, careful.val_objects)
    assert 0.25 < len(noisy.val_labelled) / (len(noisy.val_labelled) + len(noisy.train_labelled)) < 0.35


def test_verified_pair_scores_take_each_links_association_score():
    from research.experiments.levers import verified_pair_scores

    scene = _toy_scene(n_tracks=2, length=3)
    scene = dataclasses.replace(scene, link_score=np.array([np.nan, 0.8, 0.6, np.nan, 0.9, 0.7], np.float32)[
        : len(scene)], fragment_pairs=np.array([[4, 1]]), fragment_scores=np.array([0.4], np.float32))
    pairs = np.array([[0, 1], [1, 2], [4, 1], [5, 3]])
    # a track link: the later sample's link score; a stitch: its shared-point share; unknown: 1
    assert np.allclose(verified_pair_scores(scene, pairs), [0.8, 0.6, 0.4, 1.0])
