"""`tracklabel experiment paper` end to end at a toy size (the real default takes 20-60 minutes, by host)."""

from __future__ import annotations

import json

import numpy as np
import yaml
from typer.testing import CliRunner

from app.cli import app
from research.configs import CONFIG_DIR

runner = CliRunner()


def test_cli_experiment_paper_writes_tables_json_and_plots(tmp_path):
    out = tmp_path / "paper"
    r = runner.invoke(
        app,
        ["experiment", "paper", "--out", str(out), "--config", "paper-smoke", "--config", "paper-ablations"],
    )
    assert r.exit_code == 0, r.output
    doc = json.loads((out / "paper.json").read_text())
    assert list(doc["results"]) == ["baseline_min", "constraint30", "constraint60", "constraint100", "baseline_max",
                                    "constraint100_auto", "constraint100_tracks_only", "constraint100_paper_pairs", "constraint100_no_mask",
                                    "constraint100_no_closure", "constraint100_paper_batch", "constraint100_closure_only", "constraint100_sample_closure", "constraint100_no_unknown",
                                    "oracle_objects20",
                                    "oracle_object_constraints"]
    assert doc["results"]["constraint100_paper_pairs"]["training"]["transitive_pairs"] is False
    assert doc["results"]["constraint100_no_mask"]["training"]["foreground_channel"] is False
    assert doc["results"]["constraint100_no_closure"]["training"]["closure_labels"] is False
    assert doc["results"]["constraint100_auto"]["training"]["closure_labels"] is False  # unverified pairs
    assert doc["config"]["training"]["closure_labels"] is True
    assert doc["config"]["unknown_constraints"] is True  # the default; constraint100_no_unknown: the paper's
    assert doc["config"]["training"]["closure_draw"] == "annotation"  # labels via constraints: per annotation
    assert doc["results"]["constraint100_sample_closure"]["training"]["closure_draw"] == "sample"
    assert "closure_draw" not in doc["results"]["constraint100"]["training"]  # the config's
    assert "drawn per annotation" in (out / "paper.md").read_text()
    m = doc["config"]["paper_batch_labelled"]
    big = m * (1 + 2 * doc["config"]["paper_pairs_per_label"])  # the paper step's canvases
    for name in ("baseline_min", "baseline_max", "oracle_objects20"):  # labels only: both tried, the better kept
        row = doc["results"][name]
        tried = {int(k): v for k, v in row["batch_select"].items()}
        assert set(tried) == {m, big} and row["training"]["batch_labelled"] == max(tried, key=lambda b: (tried[b], -b))
    # constraint settings: 1 pair per label at a constraint step's canvases (58 + 58 of 176);
    # constraint100_paper_batch keeps the paper's m labels + 5 m pairs
    assert doc["config"]["constraint_batch"] == {"batch_labelled": big // 3, "pairs_per_label": 1}
    for name in ("constraint30", "constraint100", "constraint100_auto", "oracle_object_constraints"):
        tr = doc["results"][name]["training"]
        assert tr["batch_labelled"] == big // 3 and "pairs_per_label" not in tr  # the training config's 1
    tr = doc["results"]["constraint100_paper_batch"]["training"]
    assert (tr["batch_labelled"], tr["pairs_per_label"]) == (m, doc["config"]["paper_pairs_per_label"])
    tr = doc["results"]["constraint100_closure_only"]["training"]
    assert (tr["batch_labelled"], tr["pairs_per_label"]) == (big, 0)
    assert f"{big // 3} labels + {big // 3} pairs (the paper's step: {m} + {m * doc['config']['paper_pairs_per_label']})" in (out / "paper.md").read_text()
    assert "batch_select" not in doc["results"]["constraint100"]
    data = doc["data"]
    assert data["baseline_min"]["closure_labels"] == data["baseline_min"]["labels"]  # no pairs: nothing spreads
    assert data["constraint100_no_closure"]["closure_labels"] == data["constraint100_no_closure"]["labels"]
    assert sum(data["constraint100"]["closure_labels"]) >= sum(data["constraint30"]["closure_labels"]) >= sum(data["constraint30"]["labels"])
    ad = doc["adaptation"]
    assert set(ad) == {"adapt_constraints_only", "adapt_constraints_only_balance", "constraint100_before"}
    assert ad["adapt_constraints_only_balance"]["balance_weight"] > 0 == ad["adapt_constraints_only"]["balance_weight"]
    assert abs(sum(ad["adapt_constraints_only"]["predicted_share"]) - 1.0) < 1e-3
    for row in doc["results"].values():
        assert row["steps"] == 4 and len(row["train_loss"]) == 2 and {"train_val", "val", "test"} <= set(row)
    assert doc["data"]["constraint30"]["pairs"] <= doc["data"]["constraint100"]["pairs"]
    assert "test_gain_constraint100_over_baseline_min" in doc["targets"]
    assert (doc["config"]["train_style"], doc["config"]["test_style"]) == ("a+", "b+")  # the varied campus
    md = (out / "paper.md").read_text()
    assert "| sup. (oracle) | oracle_objects20 |" in md
    assert "| semi-sup. | constraint100 |" in md and "test scene D" in md and "Constraints only on D" in md
    assert (out / "paper_train.png").stat().st_size > 1000 and (out / "paper_test.png").stat().st_size > 1000


def test_cli_experiment_paper_default_runs_the_issues_settings(tmp_path):
    out = tmp_path / "paper"
    r = runner.invoke(
        app,
        ["experiment", "paper", "--out", str(out), "--config", "paper-smoke", "--set", "steps=2", "--set", "evals=1",
         "--set", "labels_per_class=2", "--set", "eval_max=100"],
    )
    assert r.exit_code == 0, r.output
    doc = json.loads((out / "paper.json").read_text())
    assert list(doc["results"]) == ["baseline_min", "constraint30", "constraint60", "constraint100", "baseline_max",
                                    "constraint100_auto"]
    assert doc["config"]["labels_only_batch"] == "select" and "ordering_train_val" in doc["targets"]


def test_cli_experiment_paper_rejects_bad_configs(tmp_path):
    for args, msg in (
        (["--set", "frames=5"], "frames"),
        (["--set", "bridge_pixels=0"], "bridge_pixels"),
        (["--set", "labels_only_batch=big"], "labels_only_batch"),
        (["--set", "training.closure_draw=track"], "training.closure_draw"),
        (["--set", "training.pairs_per_label=-1"], "training.pairs_per_label"),
        (["--set", "settings=[constraint200]"], "constraint200"),
        (["--set", "test_style=z"], "test_style"),
        (["--config", "nonesuch"], "paper-full"),
        (["--set", "frames"], "KEY=VALUE"),
    ):
        r = runner.invoke(app, ["experiment", "paper", "--out", str(tmp_path), *args])
        assert r.exit_code == 2 and msg in r.output, (args, r.output)
    assert not (tmp_path / "cache").exists()  # refused before simulating anything


def test_cli_experiment_paper_config_file_overrides_apply_in_order(tmp_path):
    from research.configs import load_experiment_config
    from research.experiments.paper import PaperConfig

    own = tmp_path / "mine.yaml"
    own.write_text("frames: 300\ntraining:\n  lr: 0.002\n")
    cfg = load_experiment_config(PaperConfig, ["paper-full", str(own)], ["steps=10", "training.threads=1"])
    assert (cfg.frames, cfg.labels_per_class, cfg.steps) == (300, 350, 10)  # full, then mine, then --set
    assert (cfg.training.lr, cfg.training.threads, cfg.training.batch_labelled) == (0.002, 1, 58)


def test_a_nested_override_keeps_the_rest_of_a_non_default_nested_default():
    from research.configs import load_experiment_config
    from research.experiments.default_model import DefaultModelConfig

    # the shipped model trains 8 x 50 steps on one thread; another training seed must not undo that
    cfg = load_experiment_config(DefaultModelConfig, [], ["training.seed=1"])
    assert (cfg.training.seed, cfg.training.steps_per_epoch, cfg.training.threads) == (1, 50, 1)
    assert load_experiment_config(DefaultModelConfig) == DefaultModelConfig()


def test_cli_experiment_levers_scores_each_lever_on_validation_and_measures_the_pull(tmp_path):
    out = tmp_path / "levers"
    smoke = yaml.safe_load((CONFIG_DIR / "paper-smoke.yaml").read_text())
    cfg = tmp_path / "levers.yaml"
    cfg.write_text(yaml.safe_dump({"paper": smoke | {"settings": ["baseline_min"], "adapt": []},
                                   "levers": ["constraint100", "squared_difference", "score_weighted"]}))
    r = runner.invoke(app, ["experiment", "levers", "--out", str(out), "--config", str(cfg)])
    assert r.exit_code == 0, r.output
    doc = json.loads((out / "levers.json").read_text())
    assert list(doc["validation"]) == ["baseline_min", "baseline_max", "constraint100", "squared_difference",
                                       "score_weighted"]
    assert "test" not in json.dumps(doc["validation"])  # chosen on validation, never on D
    pull = doc["pull"]
    assert 0 < pull["unlabelled_component_pairs"] <= pull["pairs"]
    for table in pull["tables"].values():  # every drawn pair counted once per model
        assert np.asarray(table).sum() == pull["unlabelled_component_pairs"]
    assert "## The pull" in (out / "levers.md").read_text() and (out / "levers.png").stat().st_size > 1000
