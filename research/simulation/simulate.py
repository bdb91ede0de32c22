"""`simulate_sequence`: the synthetic campus scene written as a SemanticKITTI sequence.

Per frame k (time k / 10 s):
  1. pose the ego vehicle (T_scene_lidar) on its route;
  2. gather the static primitives and actors within range, posed at time k / 10;
  3. window each primitive onto the rays it can hit and cast the revolution;
  4. turn hits into returns (dropouts, noise, remission, labels);
  5. write velodyne/NNNNNN.bin and labels/NNNNNN.label.
Then poses.txt (T_world_lidar, world = the first written frame), calib.txt (identity Tr),
times.txt and metadata.json (sensor, seed, frames, route, per-instance ground truth).
Every random draw of frame k comes from (seed, k), so a frame does not depend on `start`.
Each revolution is a snapshot at time k / 10 (no skew from motion during the sweep, as in
motion-compensated scans), so static points map to the same world surface in every frame.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from pipeline import __version__
from pipeline.classes import POINT_CLASSES, UNLABELLED, to_ours
from pipeline.errors import ConfigError, DataError
from pipeline.io.semantickitti import (
    frame_name,
    write_bin,
    write_calib_identity,
    write_label,
    write_poses,
    write_times,
)
from pipeline.progress import QUIET, Progress
from pipeline.sensors import PRESETS, SensorModel
from research.simulation.raycast import cast, ray_directions, ray_windows
from research.simulation.returns import BEAM_BIAS, Returns, make_returns
from research.simulation.scene import SENSOR_HEIGHT, Scene, build_scene
from research.simulation.style import get_style

SENSOR = "hdl32e"  # the campus's own scanner; `simulate_sequence(sensor=...)` casts another preset
GENERATOR = "tracklabel simulate"


@dataclass(frozen=True)
class SimulationSummary:
    """What a simulation run wrote, and how fast.

    class_points / class_instances: points and distinct instances per class (ours) over the run.
    """

    out: Path
    sensor: str
    seed: int
    start: int
    frames: int
    points_mean: float
    points_min: int
    points_max: int
    class_points: dict[str, int]
    class_instances: dict[str, int]
    moving_instances: int
    route_length: float
    distance: float
    scene_seconds: float
    seconds: float
    dark_cars: int = 0
    extra: dict[str, float] = field(default_factory=dict)  # ms per frame per stage

    @property
    def fps(self) -> float:
        return self.frames / self.seconds if self.seconds > 0 else float("inf")

    def describe(self) -> str:
        lines = [
            f"wrote {self.frames} frames ({self.sensor}, seed {self.seed}, frames {self.start}.."
            f"{self.start + self.frames - 1}) to {self.out}",
            f"points/frame: mean {self.points_mean:.0f}  min {self.points_min}  max {self.points_max}",
            f"route: loop {self.route_length:.0f} m, driven {self.distance:.1f} m",
            "instances (points):  "
            + "  ".join(
                f"{name} {self.class_instances.get(name, 0)} ({self.class_points.get(name, 0)})"
                for name in POINT_CLASSES
                if name != "ground"
            ),
            f"ground points: {self.class_points.get('ground', 0)};  moving instances: {self.moving_instances};"
            f"  dark cars: {self.dark_cars}",
            f"speed: {self.fps:.1f} frames/s ({self.seconds:.1f} s) + scene build {self.scene_seconds:.1f} s",
        ]
        return "\n".join(lines)


def simulate_frame(
    scene: Scene,
    index: int,
    dirs: np.ndarray | None = None,
    timings: dict[str, float] | None = None,
    sensor: SensorModel | None = None,
) -> tuple[np.ndarray, Returns]:
    """(T_scene_lidar (4, 4), returns) of frame `index` (time index / 10 s) of `scene`.

    timings, when given, accumulates seconds per stage: scene (pose and primitives in range),
    windows, cast, returns. sensor: the campus's HDL-32E unless given (at most 64 beams; the
    texture comparison with real HDL-64E scans casts the campus with an HDL-64E).
    """
    sensor = sensor or PRESETS[SENSOR]
    assert sensor.n_rings <= len(BEAM_BIAS), sensor.n_rings
    dirs = ray_directions(sensor) if dirs is None else dirs
    clock = [time.perf_counter()]

    def lap(stage: str) -> None:
        if timings is not None:
            now = time.perf_counter()
            timings[stage] = timings.get(stage, 0.0) + now - clock[0]
            clock[0] = now

    t = index / sensor.frequency_hz
    pose = scene.sensor_pose(t)
    rot, origin = pose[:3, :3], pose[:3, 3]
    prims = scene.primitives_near(t, origin, sensor.max_range)
    lap("scene")
    windows = ray_windows(prims, rot, origin, sensor)
    lap("windows")
    rng = np.random.default_rng([scene.seed, index])
    hits = cast(dirs, rot, origin, prims, windows, scene.ground, sensor.max_range, int(rng.integers(2**63)))
    lap("cast")
    returns = make_returns(hits, prims, dirs, sensor, rng)
    lap("returns")
    return pose, returns


def _prepare(out: Path) -> None:
    """Create OUT/velodyne and OUT/labels; clear frames of an earlier simulation there."""
    velodyne, labels = out / "velodyne", out / "labels"
    old = sorted(velodyne.glob("*.bin")) if velodyne.is_dir() else []
    if old:
        meta = out / "metadata.json"
        try:
            ours = json.loads(meta.read_text()).get("generator") == GENERATOR
        except (OSError, ValueError):
            ours = False
        if not ours:
            raise DataError(
                out,
                "already holds a sequence that `tracklabel simulate` did not write; choose another folder",
            )
        for f in [*old, *sorted(labels.glob("*.label"))]:
            f.unlink()
    velodyne.mkdir(parents=True, exist_ok=True)
    labels.mkdir(parents=True, exist_ok=True)


def simulate_sequence(
    out: str | Path,
    frames: int,
    seed: int,
    start: int = 0,
    progress: Progress = QUIET,
    crowd: float = 1.0,
    cyclists: float = 1.0,
    style: str = "a",
    sensor: str = SENSOR,
) -> SimulationSummary:
    """Simulate frames start .. start + frames - 1 of the campus scene of `seed` into `out`.

    crowd: factor on the number of moving actors (pedestrians, cyclists, traffic); 1 = default.
    cyclists: a further factor on the number of cyclists.
    style: the campus style, the distributions objects are drawn from ("a" = default; "b" =
    another part of town; "a+" / "b+" the same with more kinds per class, see
    `research.simulation.style`).
    sensor: the preset cast (`pipeline.sensors.PRESETS`): the campus's HDL-32E by default, or
    e.g. "hdl64e" to train for KITTI's scanner (the canvases of a sample follow the beams).
    """
    _check_arguments(frames, start, crowd, cyclists, style, sensor)
    out = Path(out)
    _prepare(out)
    model = PRESETS[sensor]
    t0 = time.perf_counter()
    scene = build_scene(seed, crowd, cyclists, style)
    t1 = time.perf_counter()
    tally = _write_frames(out, scene, start, frames, model, progress)
    T_world_scene = np.linalg.inv(tally.poses[0])
    write_poses(out / "poses.txt", T_world_scene[None] @ tally.poses)
    write_calib_identity(out / "calib.txt")
    write_times(out / "times.txt", (start + np.arange(frames)) / model.frequency_hz)
    distance = float(
        scene.ego.s_at((start + frames - 1) / model.frequency_hz)
        - scene.ego.s_at(start / model.frequency_hz)
    )
    _write_metadata(out, scene, start, frames, distance, T_world_scene, tally.seen, model)
    t2 = time.perf_counter()
    return _summary(out, scene, tally, model.name, start, frames, distance, t1 - t0, t2 - t1)


def _check_arguments(frames: int, start: int, crowd: float, cyclists: float, style: str, sensor: str) -> None:
    if sensor not in PRESETS:
        raise ConfigError(f"sensor must be one of {', '.join(PRESETS)}, got {sensor!r}")
    if PRESETS[sensor].n_rings > len(BEAM_BIAS):
        raise ConfigError(f"sensor {sensor}: the simulator casts at most {len(BEAM_BIAS)} beams")
    if frames < 1:
        raise ConfigError(f"frames must be >= 1, got {frames}")
    for name, v in (("crowd", crowd), ("cyclists", cyclists)):
        if not (0.0 < v <= 10.0):
            raise ConfigError(f"{name} must be in (0, 10], got {v}")
    try:
        get_style(style)
    except ValueError as exc:
        raise ConfigError(str(exc)) from None
    if start < 0:
        raise ConfigError(f"start must be >= 0, got {start}")


@dataclass
class _FrameTally:
    """What `_write_frames` gathers: poses: (F, 4, 4) T_scene_lidar; n_points: (F,) points per
    frame; class_points: (256,) points per class (ours); seen: instance id -> frames it appears in;
    stages: seconds per stage, summed over frames."""

    poses: np.ndarray
    n_points: np.ndarray
    class_points: np.ndarray = field(default_factory=lambda: np.zeros(256, np.int64))
    seen: dict[int, int] = field(default_factory=dict)
    stages: dict[str, float] = field(default_factory=dict)


def _write_frames(out: Path, scene: Scene, start: int, frames: int, sensor: SensorModel,
                  progress: Progress) -> _FrameTally:
    """Cast and write OUT/velodyne/NNNNNN.bin and OUT/labels/NNNNNN.label of each frame."""
    dirs = ray_directions(sensor)
    tally = _FrameTally(np.zeros((frames, 4, 4)), np.zeros(frames, np.int64))
    stages = tally.stages
    for i in progress.iterate(range(frames), "simulate"):
        pose, ret = simulate_frame(scene, start + i, dirs, stages, sensor)
        tally.poses[i] = pose
        name = frame_name(i)
        tw = time.perf_counter()
        write_bin(out / "velodyne" / f"{name}.bin", ret.points, ret.remission)
        write_label(out / "labels" / f"{name}.label", ret.semantic, ret.instance)
        stages["write"] = stages.get("write", 0.0) + time.perf_counter() - tw
        tally.n_points[i] = len(ret.points)
        tally.class_points += np.bincount(to_ours(ret.semantic), minlength=256)
        for iid in np.unique(ret.instance[ret.instance > 0]).tolist():
            tally.seen[iid] = tally.seen.get(iid, 0) + 1
    return tally


def _summary(
    out: Path, scene: Scene, tally: _FrameTally, sensor: str, start: int, frames: int, distance: float,
    scene_seconds: float, seconds: float,
) -> SimulationSummary:
    seen, class_points, n_points = tally.seen, tally.class_points, tally.n_points
    class_instances: dict[str, int] = {}
    for iid in seen:
        name = scene.instances[iid].cls
        class_instances[name] = class_instances.get(name, 0) + 1
    return SimulationSummary(
        out=out,
        sensor=sensor,
        seed=int(scene.seed),
        start=int(start),
        frames=int(frames),
        points_mean=float(n_points.mean()),
        points_min=int(n_points.min()),
        points_max=int(n_points.max()),
        class_points={name: int(class_points[i]) for i, name in enumerate(POINT_CLASSES)}
        | {"unlabelled": int(class_points[UNLABELLED])},
        class_instances=class_instances,
        moving_instances=sum(1 for iid in seen if scene.instances[iid].moving),
        route_length=scene.route.length,
        distance=distance,
        scene_seconds=scene_seconds,
        seconds=seconds,
        dark_cars=sum(1 for iid in seen if scene.instances[iid].dark),
        extra={f"ms_{k}": 1000.0 * v / frames for k, v in tally.stages.items()},
    )


def _write_metadata(
    out: Path,
    scene: Scene,
    start: int,
    frames: int,
    distance: float,
    T_world_scene: np.ndarray,
    seen: dict[int, int],
    sensor: SensorModel,
) -> None:
    instances = {}
    for iid, info in scene.instances.items():
        entry: dict[str, object] = {
            "class": info.cls,
            "kind": info.kind,
            "semantic": list(info.semantic),
            "moving": info.moving,
            "frames_seen": seen.get(iid, 0),
        }
        if info.dark:
            entry["dark"] = True
        if info.position is not None:
            p = T_world_scene[:3, :3] @ np.asarray(info.position) + T_world_scene[:3, 3]
            entry["position"] = [round(float(v), 3) for v in p]
        instances[str(iid)] = entry
    meta = {
        "generator": GENERATOR,
        "version": __version__,
        "sensor": sensor.name,
        "sensor_model": sensor.to_dict(),
        "sensor_height_m": SENSOR_HEIGHT,
        "seed": int(scene.seed),
        "crowd": scene.crowd,
        "cyclists": scene.cyclists,
        "style": scene.style,
        "start": int(start),
        "frames": int(frames),
        "frame_rate_hz": sensor.frequency_hz,
        "route_length_m": round(scene.route.length, 3),
        "distance_m": round(distance, 3),
        "scan_order": "beam by beam from the top beam, each beam in azimuth column order",
        "poses": "T_world_lidar; world = the lidar frame of the first written frame",
        "T_world_scene": [[float(v) for v in row] for row in T_world_scene],
        "instances": instances,
    }
    (out / "metadata.json").write_text(json.dumps(meta, indent=1) + "\n")
