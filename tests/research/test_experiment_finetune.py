"""`tracklabel experiment finetune`: the simulated operator and the CLI's argument checks (the
experiment itself runs for minutes; its numbers are in the README)."""

from __future__ import annotations

import numpy as np
from typer.testing import CliRunner

from app.cli import app
from research.experiments.data import SceneSamples
from research.experiments.finetune import (
    FinetuneExperimentConfig,
    choose_strategy,
    finetune_target,
    reviewed_constraints,
    reviewed_tracks,
    seed_spread,
    simulated_answers,
)

runner = CliRunner()


def _scene() -> SceneSamples:
    # 3 tracks: track 1 (car, 3 samples, all labelled), track 2 (person, the operator truncated its
    # last sample), track 3 (mostly ground: nothing labelled)
    m = 7
    gt_class = np.array([1, 1, 1, 0, 0, 4, 7], np.int16)
    label = np.array([1, 1, 1, 0, 0, -1, -1], np.int16)
    return SceneSamples(
        samples=np.zeros((m, 4, 8, 8), np.uint8),
        frame=np.array([0, 1, 2, 0, 1, 2, 0], np.int32),
        segment=np.arange(m, dtype=np.int32),
        track=np.array([1, 1, 1, 2, 2, 2, 3], np.int64),
        link_score=np.full(m, 0.9, np.float32),
        gt_class=gt_class,
        gt_object=np.arange(m, dtype=np.int64),
        gt_purity=np.ones(m, np.float32),
        progress=np.zeros(m, np.float32),
        label=label,
        verified_pairs=np.zeros((0, 2), np.int64),
        auto_pairs=np.zeros((0, 2), np.int64),
        auto_scores=np.zeros(0, np.float32),
    )


def test_simulated_operator_answers_samples_from_truth():
    idx, y, confirmed, rejected = simulated_answers(_scene(), np.array([0, 5, 6]), np.array([1, 2, 3]), False)
    assert idx.tolist() == [0, 5] and y.tolist() == [1, 4]  # sample 6 is mostly ground: rejected
    assert (confirmed, rejected) == (2, 1)


def test_simulated_operator_labels_whole_tracks_as_reviewed():
    idx, y, confirmed, rejected = simulated_answers(_scene(), np.array([0, 3, 6]), np.array([1, 2, 3]), True)
    assert idx.tolist() == [0, 1, 2, 3, 4] and y.tolist() == [1, 1, 1, 0, 0]  # truncated track 2 keeps 2
    assert (confirmed, rejected) == (2, 1)


def _point(strategy: str, budget: int, mean_f: float, held: float, ref: float) -> dict:
    return {"strategy": strategy, "budget": budget, "mean_f": mean_f, "held_out_mean_f": held,
            "held_out_baseline_max_mean_f": ref}


def test_strategy_is_chosen_on_the_development_scene_by_held_out_f():
    dev = [_point("track", 20, 95.0, 70.0, 88.0), _point("diverse", 20, 89.0, 88.5, 88.0),
           _point("track", 10, 99.0, 99.0, 88.0)]
    assert choose_strategy(dev, 20) == "diverse"  # not the best F on all samples, nor another budget's


def test_finetune_target_compares_held_out_f_with_baseline_max_on_the_same_samples():
    d = [_point("diverse", 20, 90.5, 83.1, 89.7), _point("track", 20, 70.0, 95.0, 80.0)]
    t = finetune_target(d, "diverse", 20)  # the chosen strategy's, even where another does better on D
    assert (t["held_out_mean_f"], t["baseline_max_held_out_mean_f"], t["met"]) == (83.1, 89.7, False)
    assert t["mean_f_all_of_d"] == 90.5  # above baseline_max on all of D: not what the target reads


def test_cli_refuses_bad_arguments(tmp_path):
    for args, msg in (
        (["--set", "strategies=[random]"], "unknown random"),
        (["--set", "budgets=[2,x]"], "budgets"),
        (["--set", "budgets=[0]"], "budgets >= 1"),
        (["--set", "constraints=all"], "constraints"),
    ):
        r = runner.invoke(app, ["experiment", "finetune", "--out", str(tmp_path), *args])
        assert r.exit_code == 2 and msg in r.output, (args, r.output)


def test_only_the_reviewed_tracks_give_constraints():
    scene = _scene()
    pairs = np.array([[0, 1], [1, 2], [3, 4], [2, 3]])  # inside track 1, inside track 2, a stitch 1-2
    assert reviewed_constraints(scene, pairs, np.array([1])).tolist() == [[0, 1], [1, 2]]
    assert reviewed_constraints(scene, pairs, np.array([1, 2])).tolist() == pairs.tolist()
    assert reviewed_constraints(scene, pairs, np.zeros(0, np.int64)).shape == (0, 2)  # sample anchors: none


def test_a_review_budget_adds_random_tracks_up_to_the_budget():
    scene = _scene()
    assert reviewed_tracks(scene, np.array([1]), None, 3, 0).tolist() == [1]  # the anchors' tracks only
    assert reviewed_tracks(scene, np.array([1]), 1, 3, 0).tolist() == [1]
    assert reviewed_tracks(scene, np.array([1]), 2, 3, 0).tolist() == [1, 2]  # 3 has 1 sample: not drawn
    assert reviewed_tracks(scene, np.array([1]), 5, 1, 0).tolist() == [1, 2, 3]  # no more tracks than the scene's


def test_seed_spread_gives_mean_and_range_over_the_scenes():
    def target(f: float, ref: float, review: int | None = None) -> dict:
        return {"review_budget": review, "budget": 20, "held_out_mean_f": f, "baseline_max_held_out_mean_f": ref,
                "gain": f - ref, "met": f >= ref}

    (s,) = seed_spread({1000: [target(80.0, 85.0)], 1001: [target(90.0, 86.0)], 1002: [target(85.0, 84.0)]})
    assert s["finetuned"] == {"mean": 85.0, "min": 80.0, "max": 90.0, "values": [80.0, 90.0, 85.0]}
    assert (s["gain"]["mean"], s["gain"]["min"], s["gain"]["max"], s["met"]) == (0.0, -5.0, 4.0, 2)


def test_the_experiment_runs_on_the_paper_experiments_scenes():
    from research.experiments.paper import PaperConfig
    from research.experiments.paper_report import TEST_SEED_OFFSET

    cfg, paper = FinetuneExperimentConfig(), PaperConfig()
    assert (cfg.train_style, cfg.test_style) == (paper.train_style, paper.test_style) == ("a+", "b+")
    assert (cfg.train_seed, cfg.train_frames, cfg.test_frames, cfg.crowd, cfg.cyclists) == (
        paper.seed, paper.frames, paper.test_frames, paper.crowd, paper.cyclists)
    assert cfg.test_seeds == (paper.seed + TEST_SEED_OFFSET,)
    assert cfg.paper_config().unknown_constraints == paper.unknown_constraints


def test_cli_experiment_finetune_smoke_writes_tables_and_curves(tmp_path):
    import json

    out = tmp_path / "ft"
    r = runner.invoke(app, ["experiment", "finetune", "--out", str(out), "--config", "finetune-smoke"])
    assert r.exit_code == 0, r.output
    doc = json.loads((out / "finetune.json").read_text())
    assert set(doc["pretrained"]) == {"1000", "1001"}
    assert set(doc["pretrained"]["1000"]) == {"baseline_min", "constraint100", "baseline_max"}
    assert [(run["strategy"], run["budget"]) for run in doc["dev_runs"]] == [("confident", 2), ("track_diverse", 2)]
    dev = {run["strategy"]: run for run in doc["dev_runs"]}
    assert dev["confident"]["pairs"] == 0 < dev["track_diverse"]["pairs"]  # sample anchors accept no track
    chosen = doc["chosen"]["strategy"]
    for seed in ("1000", "1001"):  # D scores the chosen one, with the reviewed anchors only and the review budget
        assert [(run["strategy"], run["budget"], run["review_budget"]) for run in doc["runs"][seed]] == [
            (chosen, 2, None), (chosen, 2, 60)]
    anchors, budget = doc["runs"]["1000"]
    assert anchors["held_out_mean_f"] == doc["targets"]["1000"][0]["held_out_mean_f"]
    scored = sum(c["support"] for c in doc["pretrained"]["1000"]["baseline_max"]["report"]["per_class"].values())
    for run in (anchors, budget):
        assert run["labelled_samples"] > 0
        assert sum(run["held_out_support"]) == scored - run["labelled_samples"]  # D without what the operator labelled
    assert budget["reviewed_tracks"] == 60 and anchors["reviewed_tracks"] < 60
    assert budget["labelled_samples"] > anchors["labelled_samples"] and budget["pairs"] >= anchors["pairs"]
    assert [(s["review_budget"], s["budget"], s["seeds"]) for s in doc["spread"]] == [
        (None, 2, [1000, 1001]), (60, 2, [1000, 1001])]
    assert doc["config"]["finetune_steps_per_epoch"] == 1 and doc["seconds"]["total"] > 0
    md = (out / "finetune.md").read_text()
    assert "constraint100 + fine-tuning" in md and doc["protocol"] in md
    for name in ("finetune_f.png", "finetune_curve.png", "finetune_curve.json"):
        assert (out / name).stat().st_size > 100
