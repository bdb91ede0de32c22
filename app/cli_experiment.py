"""`tracklabel experiment ...`: the experiments on simulated scenes (research/), imported inside each command."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from app.cli_common import friendly_errors
from pipeline.progress import TqdmProgress

experiment_app = typer.Typer(no_args_is_help=True, help="Experiments on simulated scenes: the paper's tables, fine-tuning, the default model.")


ConfigNames = Annotated[list[str] | None, typer.Option(
    "--config", help="A named config of research/configs (e.g. paper-full, paper-ablations, paper-smoke) or a "
    "YAML file of overrides; repeatable, applied in order.")]
ConfigSets = Annotated[list[str] | None, typer.Option(
    "--set", help="KEY=VALUE override after the configs, e.g. frames=400 or training.threads=1; repeatable.")]


@experiment_app.command("paper")
@friendly_errors
def experiment_paper(
    out: Annotated[Path, typer.Option("--out", help="Folder for paper.md/json/png.")] = Path("data/experiments/paper"),
    config: ConfigNames = None,
    set_: ConfigSets = None,
    cache: Annotated[Path | None, typer.Option(help="Cache of processed scenes (default OUT/cache).")] = None,
) -> None:
    """Reproduce the paper's Tables 7 and 8 on simulated data: its five settings, automatic
    constraints and the constraints-only adaptation to D (Fig. 12); with --config paper-ablations
    also the extensions' ablations and oracle diagnostics."""
    from research.configs import load_experiment_config
    from research.experiments.paper import PaperConfig, run_paper

    cfg = load_experiment_config(PaperConfig, config or (), set_ or ())
    doc = run_paper(out, cfg, cache=cache, progress=TqdmProgress(), log=lambda m: typer.echo(m, err=True))
    typer.echo((out / "paper.md").read_text())
    typer.echo(f"written: {out / 'paper.md'}, {out / 'paper.json'}, {out / 'paper_train.png'}, {out / 'paper_test.png'}"
               f" ({doc['seconds']['total']:.0f} s)")


@experiment_app.command("levers")
@friendly_errors
def experiment_levers(
    out: Annotated[Path, typer.Option("--out", help="Folder for levers.md/json/png.")] = Path("data/experiments/levers"),
    config: ConfigNames = None,
    set_: ConfigSets = None,
    cache: Annotated[Path | None, typer.Option(help="Cache of processed scenes (default OUT/cache).")] = None,
) -> None:
    """Why constraint100 trails baseline_max: each lever (a change of its training) scored on the
    validation objects, and which components of the must-link graph carry the wrong pull
    (fields: research/experiments/levers.py LeversConfig, e.g. --set paper.seed=7301)."""
    from research.configs import load_experiment_config
    from research.experiments.levers import LeversConfig, run_levers

    cfg = load_experiment_config(LeversConfig, config or (), set_ or ())
    doc = run_levers(out, cfg, cache=cache, progress=TqdmProgress(), log=lambda m: typer.echo(m, err=True))
    typer.echo((out / "levers.md").read_text())
    typer.echo(f"written: {out / 'levers.md'}, {out / 'levers.json'}, {out / 'levers.png'} ({doc['seconds']:.0f} s)")


@experiment_app.command("spread")
@friendly_errors
def experiment_spread(
    runs: Annotated[list[Path], typer.Argument(help="Output folders of `tracklabel experiment paper` runs.")],
    out: Annotated[Path, typer.Option("--out", help="Folder for spread.md/json/png.")] = Path("data/experiments/spread"),
) -> None:
    """Each target of the paper experiment as the mean and range over several runs (scene seed,
    label draw, training seed)."""
    from research.experiments.spread import markdown, write_spread

    missing = [str(r) for r in runs if not (r / "paper.json").is_file()]
    if missing:
        raise typer.BadParameter(f"no paper.json in {', '.join(missing)}")
    typer.echo(markdown(write_spread(out, list(runs))))


@experiment_app.command("finetune")
@friendly_errors
def experiment_finetune(
    out: Annotated[Path, typer.Option("--out", help="Folder for finetune.md/json/png.")] = Path("data/experiments/finetune"),
    config: ConfigNames = None,
    set_: ConfigSets = None,
    cache: Annotated[Path | None, typer.Option(help="Cache of processed scenes (default OUT/cache).")] = None,
) -> None:
    """The paper's Table 10 on a simulated new scene: baseline_min, constraint100, constraint100 +
    fine-tuning and baseline_max, and each anchor strategy's F against the confirmations
    (fields: research/experiments/finetune.py FinetuneExperimentConfig, e.g. --set budgets=[2,5])."""
    from research.configs import load_experiment_config
    from research.experiments.finetune import FinetuneExperimentConfig, run_finetune_experiment

    cfg = load_experiment_config(FinetuneExperimentConfig, config or (), set_ or ())
    doc = run_finetune_experiment(out, cfg, cache=cache, progress=TqdmProgress(), log=lambda m: typer.echo(m, err=True))
    typer.echo((out / "finetune.md").read_text())
    typer.echo(f"written: {out / 'finetune.md'}, {out / 'finetune.json'}, {out / 'finetune_f.png'}, "
               f"{out / 'finetune_curve.png'}, {out / 'finetune_curve.json'} ({doc['seconds']['total']:.0f} s)")


@experiment_app.command("default-model")
@friendly_errors
def experiment_default_model(
    out: Annotated[Path, typer.Option("--out", help="Checkpoint to write (the shipped one: pipeline/models/default.pt).")] = Path("data/default_model/default.pt"),
    config: ConfigNames = None,
    set_: ConfigSets = None,
    cache: Annotated[Path | None, typer.Option(help="Cache of processed scenes (default data/default_model_cache).")] = None,
) -> None:
    """Train the default model on the simulated campus with the product's training (the model
    `predict` and anchor proposals use when none is given); writes OUT and OUT's .json summary."""
    import json

    from research.configs import load_experiment_config
    from research.experiments.default_model import DefaultModelConfig, build_default_model

    cfg = load_experiment_config(DefaultModelConfig, config or (), set_ or ())
    summary = build_default_model(out, cfg, cache=cache, progress=TqdmProgress(), log=lambda m: typer.echo(m, err=True))
    typer.echo(json.dumps(summary, indent=1))
