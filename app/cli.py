"""The `tracklabel` command line: a thin typer app that imports heavy modules inside commands.

Library errors (`pipeline.errors.TracklabelError`) become a one-line message and exit code 2.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path
from typing import Annotated

import typer

from app.cli_common import fail, friendly_errors
from app.cli_experiment import experiment_app
from app.cli_labelsets import labelset_app
from app.cli_users import db_app, user_app
from pipeline.label_sets import DEFAULT_LABEL_SET
from pipeline.progress import TqdmProgress

app = typer.Typer(add_completion=False, no_args_is_help=True, help="Track-level LiDAR annotation.")


# options several commands share
SeqArg = Annotated[Path, typer.Argument(help="A sequence folder or LiDAR file.")]
OutOpt = Annotated[Path, typer.Option("--out", help="Output folder.")]
SensorOpt = Annotated[str, typer.Option(help="auto, a preset (hdl32e, hdl64e, vlp16) or an Ouster json.")]
PosesOpt = Annotated[str, typer.Option(help="file: the sequence's own poses; icp: estimate them.")]
ConfigOpt = Annotated[Path | None, typer.Option(help="YAML file of config overrides.")]


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
    crowd: Annotated[float, typer.Option(min=0.1, max=10.0, help="Factor on the number of people, cyclists "
                                         "and moving cars (1 = the default campus).")] = 1.0,
    cyclists: Annotated[float, typer.Option(min=0.1, max=10.0, help="A further factor on the number of "
                                            "cyclists.")] = 1.0,
    style: Annotated[str, typer.Option(help="Campus style: a (default) or b (other cars, trees, people: "
                                       "another part of town); a+ and b+ add a long tail of kinds to each "
                                       "class (pickups, groups, scooters, tree guards, kiosks, ...).")] = "a",
    sensor: Annotated[str, typer.Option(help="Scanner cast: hdl32e (the campus's), hdl64e (KITTI's) or vlp16.")] = "hdl32e",
) -> None:
    """Simulate the synthetic campus scene (an HDL-32E at 10 Hz unless --sensor) as a SemanticKITTI sequence."""
    from research.simulation import simulate_sequence

    summary = simulate_sequence(out, frames=frames, seed=seed, start=start, progress=TqdmProgress(), crowd=crowd,
                                 cyclists=cyclists, style=style, sensor=sensor)
    typer.echo(summary.describe())


@app.command()
@friendly_errors
def inspect(
    path: Annotated[Path, typer.Argument(help="A sequence folder or a LiDAR file.")],
    fmt: Annotated[str, typer.Option("--format", help="Reader name, or auto.")] = "auto",
    sensor: SensorOpt = "auto",
    label_set: Annotated[str, typer.Option(help="A preset or label set file: the classes labels are counted in.")] = DEFAULT_LABEL_SET,
) -> None:
    """Print format, sensor (beams x columns, and how it was decided), frame count, points per
    frame, poses and class histogram."""
    from pipeline.inspection import inspect_sequence
    from pipeline.label_sets import load_label_set

    info = inspect_sequence(path, fmt=fmt, sensor=sensor, label_set=load_label_set(label_set))
    for w in info.warnings:
        typer.echo(f"warning: {w}", err=True)
    typer.echo(f"path:    {info.path}")
    typer.echo(f"format:  {info.format}")
    typer.echo(f"sensor:  {info.sensor} ({info.beams} beams x {info.columns} columns), from {info.sensor_from}")
    typer.echo(f"frames:  {info.frames}")
    typer.echo(
        f"points:  min {info.points_min}  median {info.points_median:.0f}  max {info.points_max} per frame"
    )
    typer.echo(f"poses:   {info.poses}")
    if info.class_histogram is not None:
        typer.echo("classes:")
        total = max(1, sum(info.class_histogram.values()))
        for name, count in info.class_histogram.items():
            typer.echo(f"  {name:<13} {count:>10}  {100.0 * count / total:5.1f}%")


@app.command()
@friendly_errors
def process(
    seq: SeqArg,
    out: OutOpt,
    sensor: SensorOpt = "auto",
    poses: PosesOpt = "file",
    workers: Annotated[int, typer.Option(min=1, help="Processes for the per-frame stages.")] = 1,
    samples: Annotated[bool, typer.Option("--samples", help="Also write the samples as .npz.")] = False,
    size: Annotated[int | None, typer.Option(help="Sample canvas size (default from config).")] = None,
    config: ConfigOpt = None,
) -> None:
    """Segment, sample and associate a sequence: OUT/tracks/*.label, tracks.json, summary.json."""
    from pipeline.config import load_config
    from pipeline.pipeline import run_process

    cfg = load_config(config)
    if size is not None:
        cfg = cfg.override({"samples": {"size": size}})
    summary = run_process(
        seq, out, cfg, sensor=sensor, poses=poses, workers=workers, samples=samples, progress=TqdmProgress(),
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

    result = evaluate_folder(seq, out, progress=TqdmProgress())
    target = json_out or (out / "evaluation.json")
    target.write_text(json.dumps(result, indent=2))
    typer.echo(format_table(result))
    typer.echo(f"metrics written to {target}")


@app.command()
@friendly_errors
def predict(
    seq: SeqArg,
    out: OutOpt,
    model: Annotated[Path | None, typer.Option("--model", help="A checkpoint (.pt) written by training, or latest: the "
                                               "newest model trained in the data folder; default: the model shipped "
                                               "with tracklabel (trained on the simulated campus).")] = None,
    sensor: SensorOpt = "auto",
    poses: PosesOpt = "file",
    size: Annotated[int | None, typer.Option(help="Sample size; must match the model (default: the model's).")] = None,
    smooth_tracks: Annotated[bool, typer.Option(help="Average class probabilities along each track (causal).")] = False,
    device: Annotated[str, typer.Option(help="auto, cpu or cuda.")] = "auto",
    config: ConfigOpt = None,
    label_set: Annotated[str, typer.Option(help="A preset or label set file; the model must be of it.")] = DEFAULT_LABEL_SET,
) -> None:
    """Classify every valid segment: OUT/labels/*.label (SemanticKITTI), OUT/confidence/*.conf, summary.json."""
    from pipeline.config import load_config
    from pipeline.pipeline import PredictOptions, run_predict

    if model is not None and str(model) == "latest" and not model.is_file():
        model = _latest_model()
        typer.echo(f"model: {model}")
    options = PredictOptions(size=size, sensor=sensor, poses=poses, device=device, smooth_tracks=smooth_tracks,
                             label_set=label_set)
    summary = run_predict(seq, model, out, options, load_config(config), progress=TqdmProgress(),
                          log=lambda m: typer.echo(f"warning: {m}", err=True))
    seg = summary["segments_classified"]
    typer.echo(
        f"{summary['frames']} frames, {sum(seg.values())} segments classified "
        f"({', '.join(f'{k} {v}' for k, v in seg.items() if v)}), {summary['frames_per_second']} frames/s -> {out}"
    )
    scored = summary.get("frames_scored", 0)
    if "point_iou" in summary:
        typer.echo(f"point mIoU against the sequence's labels: {100 * summary['point_iou']['mean_iou']:.1f} "
                   f"(the {scored} of {summary['frames']} frames that have labels)")
    else:
        typer.echo("no frame has labels: nothing scored")


app.add_typer(experiment_app, name="experiment")
app.add_typer(db_app, name="db")
app.add_typer(user_app, name="user")
app.add_typer(labelset_app, name="labelset")


@app.command()
@friendly_errors
def serve(
    host: Annotated[str | None, typer.Option(help="Bind address (TRACKLABEL_HOST).")] = None,
    port: Annotated[int | None, typer.Option(help="Port (TRACKLABEL_PORT).")] = None,
    worker: Annotated[bool, typer.Option(help="Start job worker processes beside the API (--no-worker: none).")] = True,
    workers: Annotated[int, typer.Option(min=1, max=64, help="How many job worker processes (one job each at a time).")] = 1,
    wait: Annotated[float, typer.Option(help="Seconds to wait for the database.")] = 30.0,
    viewer: Annotated[
        bool, typer.Option("--viewer/--no-viewer", help="Also start the 3D annotator; operators sign in with their token.")
    ] = True,
    viewer_port: Annotated[int, typer.Option(help="Annotator port (the next free one when it is taken).")] = 8080,
) -> None:
    """Serve the REST API: wait for the database, upgrade it, then run uvicorn, the job workers
    (separate processes, `--workers N`) and the annotator (viser) next to it."""
    import uvicorn

    from app.core.config import Settings
    from app.core.db import make_engine, wait_for_db
    from app.core.migrate import upgrade
    from app.main import create_app
    from app.worker_processes import WorkerProcesses

    overrides: dict[str, object] = {"embedded_worker": False}
    if host is not None:
        overrides["host"] = host
    if port is not None:
        overrides["port"] = port
    settings = Settings(**overrides)  # type: ignore[arg-type]
    engine = make_engine(settings.db_url)
    wait_for_db(engine, timeout_s=wait)
    engine.dispose()
    upgrade(settings.db_url)
    typer.echo(f"serving http://{settings.host}:{settings.port}/api/v1/docs ({settings.db_url.split('://')[0]})")
    if viewer:
        annotator = _start_viewer(settings.host, settings.port, None, viewer_port)
        typer.echo(f"annotator {annotator.url} (operators sign in with their token)")
    pool = WorkerProcesses(workers if worker else 0)
    pool.start()
    _exit_on_sigterm()  # uvicorn re-raises SIGTERM after its shutdown: then stop the workers too
    if worker:
        typer.echo(f"{workers} job worker process{'es' if workers > 1 else ''} started")
    try:
        uvicorn.run(create_app(settings), host=settings.host, port=settings.port, log_level="info",
                    proxy_headers=True, forwarded_allow_ips=settings.forwarded_allow_ips)
    finally:
        pool.stop()


def _exit_on_sigterm() -> None:
    import signal

    signal.signal(signal.SIGTERM, lambda *_: sys.exit(0))


def _start_viewer(api_host: str, api_port: int, token: str | None, port: int):  # -> AnnotatorViewer
    """Start the annotator beside an API that this process is about to serve (loopback URL)."""
    from annotator_ui.main import start_viewer

    local = "127.0.0.1" if api_host in ("0.0.0.0", "::", "") else api_host
    return start_viewer(f"http://{local}:{api_port}", token, host=api_host, port=port, check=False)


LOOPBACK = ("127.0.0.1", "localhost", "::1")


@app.command()
@friendly_errors
def annotate(
    api: Annotated[str, typer.Option("--api", envvar="TRACKLABEL_API_URL", help="URL of the track service.")] = "http://127.0.0.1:8000",
    token: Annotated[
        str | None,
        typer.Option("--token", envvar="TRACKLABEL_TOKEN", help="Operator token; without one each browser tab signs in."),
    ] = None,
    host: Annotated[str, typer.Option(help="Bind address of the viewer.")] = "127.0.0.1",
    port: Annotated[int, typer.Option(min=0, max=65535, help="Viewer port (the next free one when taken).")] = 8080,
    wait: Annotated[float, typer.Option(min=0, help="Seconds to wait for the API to answer.")] = 30.0,
    insecure_single_user: Annotated[
        bool, typer.Option("--insecure-single-user", help="Allow --token on a non-loopback address: anyone who "
                           "reaches the port then acts as that token's user without signing in.")
    ] = False,
) -> None:
    """The 3D annotator (viser): review tracks of the track service at --api in the browser.
    Each tab signs in with its operator's token; a preset --token signs every tab in as one user,
    which on an address others can reach needs --insecure-single-user."""
    from annotator_ui.main import ViewerStartError, start_viewer

    if token and host not in LOOPBACK and not insecure_single_user:
        fail(f"--token would sign in everyone who reaches {host}:{port} as its user; leave it out so that each "
             "operator signs in, or pass --insecure-single-user")
        return
    try:
        viewer = start_viewer(api, token, host=host, port=port, wait_s=wait)
    except ViewerStartError as exc:
        fail(str(exc))
        return
    typer.echo(f"annotator {viewer.url} (API {api})")
    viewer.serve_forever()


@app.command()
@friendly_errors
def worker(once: Annotated[bool, typer.Option(help="Run at most one job, then exit.")] = False) -> None:
    """Run a job worker against TRACKLABEL_DATABASE_URL (scale by starting more)."""
    from app.worker import main as worker_main

    worker_main(once=once)


Port = Annotated[int, typer.Option(min=1, max=65535, help="API port.")]
ViewerPort = Annotated[int, typer.Option(min=0, max=65535, help="Annotator port (0 = any free one).")]
DataDir = Annotated[Path | None, typer.Option(
    "--data-dir", help="Database, artifacts and models (default: TRACKLABEL_DATA_DIR, else one folder per user: "
    "$XDG_DATA_HOME/tracklabel or ~/.local/share/tracklabel).")]


@app.command()
@friendly_errors
def demo(
    out: Annotated[Path, typer.Option("--out", help="Folder for the scene, database and artifacts.")] = Path("data/demo"),
    frames: Annotated[int, typer.Option(min=2, help="Frames to simulate.")] = 100,
    seed: Annotated[int, typer.Option(help="Scene seed.")] = 0,
    port: Port = 8000,
    serve_api: Annotated[bool, typer.Option("--serve/--no-serve", help="Serve after preparing.")] = True,
    viewer_port: ViewerPort = 8080,
) -> None:
    """Simulate the campus scene, register and ingest it, then serve it with the annotator signed in
    as the demo operator, and print the URLs and tokens. A busy port is an error before any work."""
    from app.demo import prepare_demo
    from app.local import check_ports

    if serve_api:
        check_ports("127.0.0.1", {"--port": port, "--viewer-port": viewer_port})
    typer.echo(f"data: {out.resolve()} (the scene, database and artifacts)")
    info = prepare_demo(out, frames=frames, seed=seed, port=port, log=typer.echo, progress=TqdmProgress())
    _print_tokens(info.settings.host, port, info.admin_token, info.operator_token)
    if serve_api:
        _serve_here(info.settings, info.operator_token, viewer_port, "the demo operator")


@app.command()
@friendly_errors
def label(
    seq: Annotated[Path, typer.Argument(help="Your recording: a sequence folder or LiDAR file, any supported format.")],
    poses: Annotated[str, typer.Option(help="file: the sequence's own poses; icp: estimate them (KISS-ICP).")] = "file",
    sensor: SensorOpt = "auto",
    fmt: Annotated[str, typer.Option("--format", help="Reader name, or auto.")] = "auto",
    name: Annotated[str | None, typer.Option(help="Sequence name (default: the folder's).")] = None,
    data_dir: DataDir = None,
    host: Annotated[str, typer.Option(help="Bind address of the API and the annotator.")] = "127.0.0.1",
    port: Port = 8000,
    viewer_port: ViewerPort = 8080,
    reingest: Annotated[bool, typer.Option(help="Process a sequence ingested before again (drops its reviews).")] = False,
    serve_api: Annotated[bool, typer.Option("--serve/--no-serve", help="Serve after preparing.")] = True,
    label_set: Annotated[str | None, typer.Option(
        help="Its classes: a preset (tracklabel labelset list) or a label set file; default paper.")] = None,
) -> None:
    """Label your own recording: register SEQ, ingest it (progress bar), serve the API and the
    annotator (signed in as the local admin), and print the address and tokens. Run it again to
    go on: the data folder keeps the tracks and reviews."""
    from app.label import Source, label_settings, prepare
    from app.local import check_ports

    if poses not in ("file", "icp"):
        fail(f"--poses {poses!r}: use file or icp")
    if serve_api:
        check_ports(host, {"--port": port, "--viewer-port": viewer_port})
    settings = label_settings(data_dir, seq, host=host, port=port)
    typer.echo(f"data: {settings.data_dir.resolve()} (database, artifacts, models)")
    src = Source(seq, name=name, fmt=fmt, sensor=sensor, poses=poses, reingest=reingest, label_set=label_set)
    ready = prepare(settings, src, log=typer.echo, progress=TqdmProgress())
    _print_tokens(host, port, ready.admin_token, ready.operator_token)
    if serve_api:
        _serve_here(settings, ready.admin_token, viewer_port, "the local admin (Jobs tab: Start training)")


@app.command()
@friendly_errors
def train(
    seq: Annotated[str, typer.Argument(help="A sequence registered by `tracklabel label`: its path or id.")],
    data_dir: DataDir = None,
    model_size: Annotated[str, typer.Option(help="tiny, small, default or large.")] = "default",
    constraints: Annotated[str, typer.Option(help="verified (of accepted tracks), automatic or none.")] = "verified",
    epochs: Annotated[int | None, typer.Option(min=1, help="Epochs (default: the library's).")] = None,
    steps_per_epoch: Annotated[int | None, typer.Option(min=1, help="Steps per epoch (default: the library's).")] = None,
) -> None:
    """Train the sample CNN on the sequence's reviewed labels and constraints (the same `train`
    job as the annotator's Start training button); prints the checkpoint for `predict --model`."""
    from app.core.config import Settings
    from app.core.db import Database
    from app.local import find_sequence, queue_job, run_job, user_id

    settings = Settings(**({"data_dir": data_dir} if data_dir else {}))
    db = Database.from_settings(settings)
    try:
        sequence = find_sequence(db, seq)
        params = {"sequence_ids": [sequence.id], "model_size": model_size, "constraints": constraints}
        params |= {k: v for k, v in (("epochs", epochs), ("steps_per_epoch", steps_per_epoch)) if v is not None}
        job_id = queue_job(db, "train", params, user_id(db, "admin"))
        result = run_job(settings, db, job_id, "train", TqdmProgress())
    finally:
        db.dispose()
    metrics = result.get("metrics") or {}
    data = metrics.get("data") or {}
    val_f = metrics.get("val_mean_f")
    typer.echo(f"model {result['model_id']}: trained on {data.get('labelled_train')} labels and {data.get('pairs')} "
               f"pairs; validation F {'-' if val_f is None else f'{val_f:.1f}'} ({data.get('labelled_val')} labels)")
    typer.echo(f"checkpoint: {result['path']}")


@app.command()
@friendly_errors
def export(
    seq: Annotated[str, typer.Argument(help="A sequence registered by `tracklabel label`: its path or id.")],
    out: OutOpt,
    data_dir: DataDir = None,
    include_ground: Annotated[bool, typer.Option(help="Write the ground class on the remaining ground points.")] = False,
    reviewed_only: Annotated[bool, typer.Option(help="Only the reviewed tracks' points (no bulk accepts, "
                                                "labels carried to nearby points or predictions).")] = False,
) -> None:
    """SemanticKITTI labels, the REST export's: OUT/sequences/NAME/labels/NNNNNN.label, one uint32
    per point of the scan (class id | track id << 16; 0 = no class), and summary.json (points per
    source and class)."""
    import numpy as np

    from app.core.config import Settings
    from app.core.db import Database
    from app.local import export_semantickitti, find_sequence
    from app.services.point_labels import ExportOptions

    settings = Settings(**({"data_dir": data_dir} if data_dir else {}))
    db = Database.from_settings(settings)
    try:
        options = ExportOptions(include_ground=include_ground, reviewed_only=reviewed_only)
        files = export_semantickitti(db, settings, find_sequence(db, seq), out, options)
    finally:
        db.dispose()
    labels = [f for f in files if f.suffix == ".label"]
    ids = np.concatenate([np.fromfile(f, np.uint32) & 0xFFFF for f in labels]) if labels else np.zeros(0, np.uint32)
    per_id = {int(k): int(v) for k, v in zip(*np.unique(ids[ids > 0], return_counts=True), strict=True)}
    typer.echo(f"{len(labels)} frames, {sum(per_id.values())} points with a class "
               f"(SemanticKITTI id: points {per_id}) -> {labels[0].parent if labels else out}")


def _latest_model() -> Path:
    from app.core.config import Settings
    from app.core.db import Database
    from app.local import latest_model

    db = Database.from_settings(Settings())
    try:
        return latest_model(db)
    finally:
        db.dispose()


def _print_tokens(host: str, port: int, admin_token: str, operator_token: str) -> None:
    typer.echo(f"\nAPI:            http://{host}:{port}/api/v1/docs")
    typer.echo(f"admin token:    {admin_token}")
    typer.echo(f"operator token: {operator_token}")
    typer.echo(f'try:  curl -H "Authorization: Bearer {operator_token}" http://{host}:{port}/api/v1/exports/stats')


def _serve_here(settings, viewer_token: str, viewer_port: int, who: str) -> None:  # settings: app Settings
    """The API, one job worker process (as `serve`) and the annotator signed in with
    `viewer_token`, until Ctrl-C."""
    import uvicorn

    from app.main import create_app
    from app.worker_processes import WorkerProcesses

    annotator = _start_viewer(settings.host, settings.port, viewer_token, viewer_port)
    typer.echo(f"\nannotator:      {annotator.url}   <- open this in a browser, signed in as {who}")
    typer.echo("keys: A accept, D discard, a class's key (beside its button: the sequence's label set), "
               "[ ] truncate, Z undo; Ctrl-C stops (the data folder keeps all)")
    pool = WorkerProcesses(1, {"TRACKLABEL_DATA_DIR": str(settings.data_dir),
                               "TRACKLABEL_DATA_ROOTS": os.pathsep.join(str(r) for r in settings.data_roots)})
    pool.start()
    _exit_on_sigterm()
    try:
        uvicorn.run(create_app(settings.model_copy(update={"embedded_worker": False})), host=settings.host,
                    port=settings.port, log_level="warning")
    finally:
        pool.stop()


def main() -> None:
    """Entry point of the `tracklabel` script."""
    try:
        app()
    except KeyboardInterrupt:
        sys.exit(130)


if __name__ == "__main__":
    main()
