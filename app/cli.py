"""The `tracklabel` command line: a thin typer app that imports heavy modules inside commands.

Library errors (`pipeline.errors.TracklabelError`) become a one-line message and exit code 2.
"""

from __future__ import annotations

import functools
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Annotated, TypeVar

import typer

app = typer.Typer(add_completion=False, no_args_is_help=True, help="Track-level LiDAR annotation.")
F = TypeVar("F", bound=Callable[..., object])


def fail(message: str) -> None:
    """Print a one-line error to stderr and exit with code 2."""
    typer.echo(f"error: {message}", err=True)
    raise typer.Exit(code=2)


def friendly_errors(func: F) -> F:
    """Turn the library's own errors into `fail(...)` instead of a traceback."""

    @functools.wraps(func)
    def wrapper(*args: object, **kwargs: object) -> object:
        from pipeline.errors import TracklabelError

        try:
            return func(*args, **kwargs)
        except (TracklabelError, KeyError, FileNotFoundError) as exc:
            msg = exc.args[0] if isinstance(exc, KeyError) and exc.args else str(exc)
            fail(str(msg))
        return None

    return wrapper  # type: ignore[return-value]


def _version(value: bool) -> None:
    if value:
        from pipeline import __version__

        typer.echo(f"tracklabel {__version__}")
        raise typer.Exit()


@app.callback()
def root(
    version: Annotated[
        bool, typer.Option("--version", callback=_version, is_eager=True, help="Print the version.")
    ] = False,
) -> None:
    """tracklabel: turn raw LiDAR sequences into labelled training data and a trained model."""


@app.command()
@friendly_errors
def simulate(
    out: Annotated[Path, typer.Argument(help="Output folder (SemanticKITTI layout).")],
    frames: Annotated[int, typer.Option(min=1, help="Number of frames.")] = 200,
    seed: Annotated[int, typer.Option(help="Scene seed: a different seed is a different layout.")] = 0,
    start: Annotated[int, typer.Option(min=0, help="First frame of the route to simulate.")] = 0,
) -> None:
    """Simulate the synthetic campus scene (HDL-32E, 10 Hz) as a SemanticKITTI sequence."""
    from pipeline.simulation import simulate_sequence

    summary = simulate_sequence(out, frames=frames, seed=seed, start=start, progress=True)
    typer.echo(summary.describe())


@app.command()
@friendly_errors
def inspect(
    path: Annotated[Path, typer.Argument(help="A sequence folder or a LiDAR file.")],
    fmt: Annotated[str, typer.Option("--format", help="Reader name, or auto.")] = "auto",
) -> None:
    """Print format, sensor, frame count, points per frame, poses and class histogram."""
    from pipeline.inspection import inspect_sequence

    info = inspect_sequence(path, fmt=fmt)
    for w in info.warnings:
        typer.echo(f"warning: {w}", err=True)
    typer.echo(f"path:    {info.path}")
    typer.echo(f"format:  {info.format}")
    typer.echo(f"sensor:  {info.sensor}")
    typer.echo(f"frames:  {info.frames}")
    typer.echo(
        f"points:  min {info.points_min}  median {info.points_median:.0f}  max {info.points_max} per frame"
    )
    typer.echo(f"poses:   {info.poses}")
    if info.class_histogram is not None:
        typer.echo("classes:")
        total = max(1, sum(info.class_histogram.values()))
        for name, count in info.class_histogram.items():
            typer.echo(f"  {name:<10} {count:>10}  {100.0 * count / total:5.1f}%")


@app.command()
@friendly_errors
def process(
    seq: Annotated[Path, typer.Argument(help="A sequence folder or LiDAR file.")],
    out: Annotated[Path, typer.Option("--out", help="Output folder.")],
    sensor: Annotated[str, typer.Option(help="auto, a preset (hdl32e, hdl64e, vlp16) or an Ouster json.")] = "auto",
    poses: Annotated[str, typer.Option(help="file: the sequence's own poses; icp: estimate them.")] = "file",
    workers: Annotated[int, typer.Option(min=1, help="Processes for the per-frame stages.")] = 1,
    samples: Annotated[bool, typer.Option("--samples", help="Also write the samples as .npz.")] = False,
    size: Annotated[int | None, typer.Option(help="Sample canvas size (default from config).")] = None,
    config: Annotated[Path | None, typer.Option(help="YAML file of config overrides.")] = None,
) -> None:
    """Segment, sample and associate a sequence: OUT/tracks/*.label, tracks.json, summary.json."""
    from pipeline.config import load_config
    from pipeline.pipeline import run_process

    cfg = load_config(config)
    if size is not None:
        cfg = cfg.override({"samples": {"size": size}})
    summary = run_process(
        seq, out, cfg, sensor=sensor, poses=poses, workers=workers, samples=samples, progress=True,
        log=lambda m: typer.echo(f"warning: {m}", err=True),
    )
    typer.echo(
        f"{summary['frames']} frames, {summary['segments']} segments ({summary['valid_segments']} valid), "
        f"{summary['tracks']} tracks ({summary['tracks_multi_frame']} multi-frame), "
        f"{summary['constraint_pairs']} constraint pairs, {summary['frames_per_second']} frames/s -> {out}"
    )


@app.command()
@friendly_errors
def evaluate(
    seq: Annotated[Path, typer.Argument(help="The sequence, with SemanticKITTI labels.")],
    out: Annotated[Path, typer.Argument(help="The output folder of `tracklabel process`.")],
    json_out: Annotated[Path | None, typer.Option("--json", help="Write the metrics here.")] = None,
) -> None:
    """Segment purity, over-segmentation and association precision/recall against labels."""
    import json

    from pipeline.evaluation import format_table
    from pipeline.pipeline import evaluate_folder

    result = evaluate_folder(seq, out, progress=True)
    target = json_out or (out / "evaluation.json")
    target.write_text(json.dumps(result, indent=2))
    typer.echo(format_table(result))
    typer.echo(f"metrics written to {target}")


def main() -> None:
    """Entry point of the `tracklabel` script."""
    try:
        app()
    except KeyboardInterrupt:
        sys.exit(130)


if __name__ == "__main__":
    main()
