from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pipeline.classes import POINT_CLASSES, to_ours
from pipeline.errors import DataError
from pipeline.io.semantickitti import read_bin, read_calib_tr, read_label, read_matrix_lines
from pipeline.sensors import PRESETS
from research.simulation import models as m
from research.simulation import simulate_frame, simulate_sequence
from research.simulation.ground import GroundModel
from research.simulation.raycast import Windows, cast, ray_directions, ray_windows
from research.simulation.returns import BEAM_BIAS, make_returns
from research.simulation.scene import build_scene
from research.simulation.shapes import (
    Material,
    PrimitiveBuilder,
    rot_x,
    rot_y,
    rot_z,
    signed_distance,
    surface_distance,
)

SEED = 3
FRAMES = 20
SENSOR = PRESETS["hdl32e"]


@pytest.fixture(scope="module")
def seq(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("sim") / "seq"
    simulate_sequence(out, frames=FRAMES, seed=SEED)
    return out


@pytest.fixture(scope="module")
def scene():
    return build_scene(SEED)


def _meta(seq: Path) -> dict:
    return json.loads((seq / "metadata.json").read_text())


def _frame(seq: Path, k: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(points (N, 4), semantic (N,), instance (N,)) of frame k."""
    b = read_bin(seq / "velodyne" / f"{k:06d}.bin")
    sem, inst = read_label(seq / "labels" / f"{k:06d}.label", expected=len(b))
    return b, sem, inst


def _columns(points: np.ndarray) -> np.ndarray:
    az = np.arctan2(points[:, 1], points[:, 0])
    return np.floor((0.5 - az / (2 * np.pi)) * SENSOR.width).astype(np.int64) % SENSOR.width


def _world_points(seq: Path, k: int) -> np.ndarray:
    pose = read_matrix_lines(seq / "poses.txt")[k]
    b, _, _ = _frame(seq, k)
    return b[:, :3].astype(np.float64) @ pose[:3, :3].T + pose[:3, 3]


def test_simulate_writes_semantickitti_layout(seq: Path):
    assert len(list((seq / "velodyne").glob("*.bin"))) == FRAMES
    assert len(list((seq / "labels").glob("*.label"))) == FRAMES
    poses = read_matrix_lines(seq / "poses.txt")
    assert poses.shape == (FRAMES, 4, 4)
    np.testing.assert_allclose(poses[0], np.eye(4), atol=1e-9)
    np.testing.assert_array_equal(read_calib_tr(seq / "calib.txt"), np.eye(4))
    np.testing.assert_allclose(np.loadtxt(seq / "times.txt"), np.arange(FRAMES) / 10.0)
    meta = _meta(seq)
    assert (meta["sensor"], meta["seed"], meta["start"], meta["frames"]) == ("hdl32e", SEED, 0, FRAMES)
    assert meta["route_length_m"] >= 300.0
    assert {"class", "moving", "semantic"} <= set(meta["instances"]["1"])


def test_simulate_all_classes_present(seq: Path):
    seen = set()
    for k in range(FRAMES):
        seen |= set(to_ours(_frame(seq, k)[1]).tolist())
    assert {POINT_CLASSES.index(c) for c in POINT_CLASSES} <= seen


def test_simulate_labels_match_instance_table(seq: Path):
    meta = _meta(seq)
    for k in (0, FRAMES - 1):
        _, sem, inst = _frame(seq, k)
        ground = to_ours(sem) == POINT_CLASSES.index("ground")
        assert np.all(inst[ground] == 0) and np.all(inst[~ground] >= 1)
        for iid in np.unique(inst[inst > 0]):
            allowed = meta["instances"][str(iid)]["semantic"]
            assert set(np.unique(sem[inst == iid]).tolist()) <= set(allowed), iid


def test_simulate_route_is_a_long_loop_with_turns(seq: Path, scene):
    assert _meta(seq)["route_length_m"] >= 300.0
    step = np.linalg.norm(np.diff(read_matrix_lines(seq / "poses.txt")[:, :3, 3], axis=0), axis=1)
    assert 0.3 < step.mean() < 0.7  # about 5 m/s at 10 Hz
    poses = np.stack([scene.sensor_pose(t) for t in np.arange(0.0, 20.0, 0.5)])
    yaw = np.unwrap(np.arctan2(poses[:, 1, 0], poses[:, 0, 0]))
    assert np.ptp(yaw) > np.deg2rad(12)  # the start lies shortly before a turn
    assert 0.3 < scene.route.straight.mean() < 0.95  # straights and turns


def test_simulate_moving_instances_move_in_world(seq: Path):
    meta = _meta(seq)
    centroids: dict[int, list[tuple[int, np.ndarray]]] = {}
    for k in range(FRAMES):
        w = _world_points(seq, k)
        _, _, inst = _frame(seq, k)
        for iid in np.unique(inst[inst > 0]):
            m = inst == iid
            if meta["instances"][str(iid)]["moving"] and m.sum() >= 15:
                centroids.setdefault(int(iid), []).append((k, w[m].mean(axis=0)))
    speeds = []
    for track in centroids.values():
        (k0, a), (k1, b) = track[0], track[-1]
        if k1 - k0 >= 10:
            speeds.append(np.linalg.norm(b[:2] - a[:2]) / ((k1 - k0) / 10.0))
    assert len(speeds) >= 3
    assert min(speeds) > 0.5  # people walk >= 0.9 m/s, cars drive >= 5.5 m/s


def _unbiased_world_points(seq: Path, k: int) -> np.ndarray:
    """World points of frame k with each beam's fixed range offset (BEAM_BIAS) taken out."""
    pose = read_matrix_lines(seq / "poses.txt")[k]
    b, _, _ = _frame(seq, k)
    p = b[:, :3].astype(np.float64)
    ring = np.concatenate([[0], np.cumsum(np.diff(_columns(p)) < 0)])  # scan order: beam by beam
    r = np.linalg.norm(p, axis=1)
    p *= ((r - BEAM_BIAS[ring]) / r)[:, None]
    return p @ pose[:3, :3].T + pose[:3, 3]


def test_simulate_points_lie_on_their_instance_surface(seq: Path, scene):
    """Static points stay on their object in world coordinates; moving ones on the actor at time t.

    World points of frames 0 and 19 (each beam's range offset taken out) are mapped to the scene
    frame with one transform (metadata T_world_scene) and compared to the instance's true
    primitives: 95 % of the points of smooth rigid surfaces within 5 cm (range noise sigma is
    0.5 cm + 0.04 % of the range) and none beyond 15 cm; bark and fence boards within their relief
    (<= 20 cm deep); foliage inside its crown or, for 95 %, within 5 cm outside it.
    """
    meta = _meta(seq)
    T_scene_world = np.linalg.inv(np.asarray(meta["T_world_scene"]))
    rigid: dict[bool, list[np.ndarray]] = {False: [], True: []}
    foliage, relief = [], []
    for k in (0, FRAMES - 1):
        w = _unbiased_world_points(seq, k)
        s = w @ T_scene_world[:3, :3].T + T_scene_world[:3, 3]
        _, _, inst = _frame(seq, k)
        for iid in np.unique(inst[inst > 0]):
            info = meta["instances"][str(iid)]
            q = s[inst == iid]
            prims = scene.instance_primitives(int(iid), k / 10.0)
            if info["class"] == "bush":
                foliage.append(signed_distance(q, prims))
            elif info["kind"] in ("tree_trunk", "fence"):
                relief.append(signed_distance(q, prims))
            else:
                rigid[info["moving"]].append(surface_distance(q, prims))
    assert len(rigid[False]) > 50 and len(rigid[True]) > 5 and len(foliage) > 10 and relief
    for moving, dists in rigid.items():
        d = np.concatenate(dists)
        assert np.percentile(d, 95) < 0.05, moving
        assert max(x.max() for x in dists) < 0.15, moving
    d = np.concatenate(relief)
    assert np.percentile(d, 5) > -0.2 and np.percentile(d, 95) < 0.05
    d = np.concatenate(foliage)
    assert np.percentile(d, 95) < 0.05 and d.max() < 0.2


def test_simulate_scan_order_is_beam_by_beam(seq: Path, scene):
    _, ret = simulate_frame(scene, 0)
    key = ret.ring.astype(np.int64) * SENSOR.width + ret.column
    assert np.all(np.diff(key) > 0)  # top beam first, each beam in column order
    b, _, _ = _frame(seq, 0)
    cols = _columns(b[:, :3])
    recovered = np.concatenate([[0], np.cumsum(np.diff(cols) < 0)])
    np.testing.assert_array_equal(recovered, ret.ring)
    el = np.arctan2(b[:, 2], np.hypot(b[:, 0], b[:, 1]))
    ring_el = np.array([np.median(el[recovered == r]) for r in np.unique(recovered)])
    assert np.all(np.diff(ring_el) < 0)


def test_simulate_points_in_range_and_remission_in_unit_interval(seq: Path):
    b, _, _ = _frame(seq, FRAMES // 2)
    r = np.linalg.norm(b[:, :3], axis=1)
    assert r.min() >= SENSOR.min_range - 0.1 and r.max() <= SENSOR.max_range + 0.1
    assert b[:, 3].min() >= 0.0 and b[:, 3].max() <= 1.0
    assert 40_000 < len(b) <= SENSOR.n_rings * SENSOR.width


def test_simulate_same_seed_identical_bytes(tmp_path: Path, seq: Path):
    a, b = tmp_path / "a", tmp_path / "b"
    simulate_sequence(a, frames=2, seed=SEED)
    simulate_sequence(b, frames=2, seed=SEED)
    files = sorted(p.relative_to(a) for p in a.rglob("*") if p.is_file())
    assert files == sorted(p.relative_to(b) for p in b.rglob("*") if p.is_file())
    for f in files:
        assert (a / f).read_bytes() == (b / f).read_bytes(), f
    for f in ("velodyne/000001.bin", "labels/000001.label"):  # and the longer run's frame 1
        assert (a / f).read_bytes() == (seq / f).read_bytes(), f


def test_simulate_start_continues_the_same_route(tmp_path: Path, seq: Path):
    simulate_sequence(tmp_path / "late", frames=2, seed=SEED, start=12)
    assert (tmp_path / "late/velodyne/000000.bin").read_bytes() == (seq / "velodyne/000012.bin").read_bytes()
    assert _meta(tmp_path / "late")["start"] == 12
    np.testing.assert_allclose(np.loadtxt(tmp_path / "late/times.txt"), [1.2, 1.3])
    late = read_matrix_lines(tmp_path / "late/poses.txt")
    full = read_matrix_lines(seq / "poses.txt")
    rel_full = np.linalg.inv(full[12]) @ full[13]
    np.testing.assert_allclose(np.linalg.inv(late[0]) @ late[1], rel_full, atol=1e-6)


def test_simulate_different_seeds_give_different_layouts(scene):
    other = build_scene(SEED + 1)
    assert other.route.length != scene.route.length
    assert len(other.static) != len(scene.static) or not np.allclose(other.static.center, scene.static.center)


def test_simulate_crowd_scales_moving_actors_and_leaves_the_static_campus(scene):
    def counts(sc) -> dict[str, int]:
        out: dict[str, int] = {}
        for a in sc.actors:
            out[a.kind] = out.get(a.kind, 0) + 1
        return out

    base = counts(scene)
    busy = build_scene(SEED, crowd=3.0, cyclists=2.0)
    more = counts(busy)
    assert more["person"] > 2 * base["person"] and more["car"] > 2 * base["car"]
    assert more["cyclist"] > 4 * base["cyclist"]  # crowd x cyclists on top
    np.testing.assert_array_equal(busy.static.center, scene.static.center)  # same layout, busier
    again = build_scene(SEED, crowd=1.0)
    assert counts(again) == base and len(again.instances) == len(scene.instances)


def test_simulate_style_b_shifts_what_objects_are_drawn_from(scene):
    from research.simulation.style import STYLES

    other = build_scene(SEED, crowd=3.0, style="b")
    base = build_scene(SEED, crowd=3.0)
    assert other.style == "b" and base.style == "a" and scene.style == "a"

    def dark_share(sc) -> float:
        cars = [i for i in sc.instances.values() if i.cls == "car"]
        return sum(i.dark for i in cars) / len(cars)

    assert dark_share(other) > dark_share(base) + 0.1  # style b: 50 % dark paint against 30 %
    assert STYLES["b"].tree_styles != STYLES["a"].tree_styles
    with pytest.raises(ValueError, match="unknown campus style"):
        build_scene(SEED, style="z")


def test_simulate_varied_style_adds_kinds_and_keeps_the_plain_draws():
    """Style "a+" is style "a" (same route, traffic, trees, people) plus the long tail of kinds
    drawn from its own streams: other car bodies, groups, child / cargo / scooter cyclists, tree
    guards, street furniture, kiosks."""
    from research.simulation.models import EXTRA_CAR_KINDS, add_car

    plain = build_scene(SEED, crowd=3.0)
    varied = build_scene(SEED, crowd=3.0, style="a+")
    assert varied.style == "a+"
    np.testing.assert_array_equal(varied.route.xy, plain.route.xy)
    assert [a.kind for a in varied.actors] == [a.kind for a in plain.actors]
    people = [(a.path.pose(3.0)[0], a.shape) for a in plain.actors if a.kind == "person"]
    people_v = [(a.path.pose(3.0)[0], a.shape) for a in varied.actors if a.kind == "person"]
    np.testing.assert_allclose([p for p, _ in people_v], [p for p, _ in people])  # same walkers, same paths
    assert [s for _, s in people_v] == [s for _, s in people]
    kinds = {i.kind for i in varied.instances.values()}
    assert {"tree_guard", "kiosk", "hydrant", "cabinet"} <= kinds
    assert not {"tree_guard", "kiosk", "hydrant", "cabinet"} & {i.kind for i in plain.instances.values()}
    assert {a.vehicle for a in varied.actors if a.kind == "cyclist"} == {"bike", "child", "cargo", "scooter"}
    assert {a.vehicle for a in plain.actors if a.kind == "cyclist"} == {"bike"}
    groups = [a for a in varied.actors if a.companions]
    assert groups and not any(a.companions for a in plain.actors)
    bodies = {a.shape.kind for a in varied.actors if a.kind == "car"}
    assert bodies & set(EXTRA_CAR_KINDS)
    # a group is one object: every member's primitives carry the actor's instance id
    g = groups[0]
    prims = g.primitives(2.0, varied.ground)
    assert set(prims.instance.tolist()) == {g.instance}
    from research.simulation.models import add_person
    from research.simulation.shapes import PrimitiveBuilder
    from research.simulation.style import STYLES

    def person_prims(shape) -> int:
        b = PrimitiveBuilder()
        add_person(b, shape, 254, 1, 0.0, 0.4)
        return len(b)

    assert len(prims) == sum(person_prims(s) for s in [g.shape, *(c[0] for c in g.companions)])
    # the extra car bodies add primitives (bed walls, cargo box) to the plain car's 14
    rng = np.random.default_rng(0)
    for kind, extra in (("pickup", 3), ("boxvan", 1), ("hatch", 0)):
        b = PrimitiveBuilder()
        add_car(b, STYLES["a"].draw_car(rng, kind=kind), 10, 1)
        assert len(b) == 14 + extra


def test_simulate_sequence_unknown_style_is_a_config_error(tmp_path: Path):
    from pipeline.errors import ConfigError

    with pytest.raises(ConfigError, match="style"):
        simulate_sequence(tmp_path / "x", frames=1, seed=0, style="z")


def test_simulate_casts_another_sensor_that_the_pipeline_then_reads(tmp_path: Path):
    from pipeline.errors import ConfigError
    from pipeline.sequence import open_sequence

    out = simulate_sequence(tmp_path / "k", frames=1, seed=SEED, sensor="hdl64e")
    assert out.sensor == "hdl64e" and _meta(tmp_path / "k")["sensor_model"]["elevations_deg"] == list(
        PRESETS["hdl64e"].elevations_deg)
    opened = open_sequence(tmp_path / "k")
    assert opened.sensor.name == "hdl64e" and opened.sensor.n_rings == 64
    scan = opened.source.frame(0)
    beams = np.unique(scan.ring)
    assert len(beams) > 50 and beams.max() == 63  # every block of the 64 beams returns points
    with pytest.raises(ConfigError, match="sensor"):
        simulate_sequence(tmp_path / "x", frames=1, seed=0, sensor="hdl128")


def test_simulate_refuses_a_foreign_sequence_folder(tmp_path: Path):
    (tmp_path / "velodyne").mkdir()
    (tmp_path / "velodyne/000000.bin").write_bytes(b"\0" * 16)
    with pytest.raises(DataError, match="did not write"):
        simulate_sequence(tmp_path, frames=1, seed=0)


def _flat_ground() -> GroundModel:
    """Grass everywhere at z = 0.1 (no road within the tiny grid)."""
    return GroundModel(
        waves=np.zeros((3, 4)),
        origin=np.array([-500.0, -500.0]),
        lat=np.full((2, 2), 1e3, np.float32),
        sidx=np.zeros((2, 2), np.int32),
        low_left=np.array([3.5], np.float32),
        low_right=np.array([3.5], np.float32),
        crossings=np.zeros(0),
        road_half=3.5,
        sidewalk_left=2.0,
        sidewalk_right=2.0,
        curb=0.1,
        route_length=100.0,
    )


def _cast_one(b: PrimitiveBuilder, origin=(0.0, 0.0, 1.8)):
    prims = b.build()
    origin = np.asarray(origin)
    dirs = ray_directions(SENSOR)
    windows = ray_windows(prims, np.eye(3), origin, SENSOR)
    return prims, dirs, cast(dirs, np.eye(3), origin, prims, windows, _flat_ground(), SENSOR.max_range, 7)


def test_raycast_box_range_is_exact():
    b = PrimitiveBuilder()
    b.box((10.0, 0.0, 1.8), (1.0, 2.0, 2.0), 50, 1, Material(refl=0.5))
    _, _, hits = _cast_one(b)
    row = int(np.argmin(np.abs(SENSOR.elevations_deg)))
    col = SENSOR.width // 2  # looks along +x
    assert hits.hit[row, col] == 0
    assert hits.t[row, col] == pytest.approx(9.0, abs=1e-3)
    ground = hits.hit[-1, 0]  # bottom beam, behind: the grass
    assert ground < -1 and hits.t[-1, 0] == pytest.approx(1.7 / np.sin(np.deg2rad(30.67)), rel=1e-3)


@settings(max_examples=15, deadline=None)
@given(
    kinds=st.lists(st.integers(0, 3), min_size=1, max_size=4),
    seed=st.integers(0, 2**31 - 1),
    tilt=st.tuples(st.floats(-0.05, 0.05), st.floats(-0.05, 0.05), st.floats(-np.pi, np.pi)),
)
def test_raycast_windows_miss_nothing(kinds, seed, tilt):
    """Property: culling rays by window changes no hit, for any primitive, pose and sensor tilt."""
    rng = np.random.default_rng(seed)
    b = PrimitiveBuilder()
    for i, kind in enumerate(kinds):
        centre = rng.uniform([-25, -25, -1], [25, 25, 4])
        size = rng.uniform(0.1, 4.0, 3)
        rot = rot_z(rng.uniform(-np.pi, np.pi)) @ rot_x(rng.uniform(-1, 1))
        mat = Material(refl=0.3)
        if kind == 0:
            b.box(centre, size, 50, i + 1, mat, rot=rot)
        elif kind == 1:
            b.cylinder(centre, size[0], size[2], 71, i + 1, mat, rot=rot)
        elif kind == 2:
            b.ellipsoid(centre, size, 70, i + 1, mat, rot=rot)
        else:
            b.capsule(centre, centre + size * rng.choice([-1, 1], 3), size[0] / 4, 30, i + 1, mat)
    prims = b.build()
    sensor_rot = rot_z(tilt[2]) @ rot_x(tilt[0]) @ rot_y(tilt[1])
    origin = np.array([0.0, 0.0, 1.8])
    dirs = ray_directions(SENSOR)
    n = len(prims)
    full = Windows(
        np.zeros(n, np.int32),
        np.full(n, 31, np.int32),
        np.zeros(n, np.int32),
        np.full(n, SENSOR.width, np.int32),
    )
    culled = ray_windows(prims, sensor_rot, origin, SENSOR)
    a = cast(dirs, sensor_rot, origin, prims, culled, _flat_ground(), SENSOR.max_range, 7)
    ref = cast(dirs, sensor_rot, origin, prims, full, _flat_ground(), SENSOR.max_range, 7)
    np.testing.assert_array_equal(a.hit, ref.hit)
    np.testing.assert_array_equal(a.t, ref.t)


def test_returns_dark_paint_loses_oblique_returns():
    counts = {}
    for name, paint in {"dark": Material(refl=0.04, spec=0.92), "bright": Material(refl=0.5)}.items():
        b = PrimitiveBuilder()
        # A wall seen at ~60 degrees incidence: cos ~ 0.5.
        b.box(
            (8.0, 0.0, 1.0),
            (0.05, 1.0, 1.0),
            10,
            1,
            paint,
            rot=np.array([[0.5, -0.866, 0], [0.866, 0.5, 0], [0, 0, 1]]),
        )
        prims, dirs, hits = _cast_one(b)
        ret = make_returns(hits, prims, dirs, SENSOR, np.random.default_rng(0))
        counts[name] = int((ret.instance == 1).sum())
    assert counts["bright"] > 100 and counts["dark"] < 0.3 * counts["bright"]


def test_cli_simulate_end_to_end(tmp_path: Path):
    from typer.testing import CliRunner

    from app.cli import app

    result = CliRunner().invoke(app, ["simulate", str(tmp_path / "cli"), "--frames", "2", "--seed", "1"])
    assert result.exit_code == 0, result.output
    assert "points/frame" in result.output
    assert len(list((tmp_path / "cli/velodyne").glob("*.bin"))) == 2


def test_simulate_walls_smooth_foliage_scattered(seq: Path):
    """On the written campus (HDL-32E) walls scatter like SemanticKITTI's walls (row residual
    median ~1 cm) and foliage several times more (docs/simulator.md)."""
    from pipeline.sequence import open_sequence
    from research.simulation.texture import texture_statistics

    source = open_sequence(seq).source
    stats = texture_statistics((source.frame(k) for k in (0, FRAMES - 1)), SENSOR)
    wall = stats["building"]["row_residual_cm"][2]
    assert 0.5 < wall < 2.0
    assert stats["vegetation"]["row_residual_cm"][2] > 3 * wall
    assert stats["vegetation"]["row_residual_over_3cm"] > 0.5 > stats["building"]["row_residual_over_3cm"]


def test_texture_line_residual_zero_on_a_ramp_and_sigma_on_noise():
    from research.simulation.texture import line_residual

    rng = np.random.default_rng(0)
    ramp = np.tile(5.0 + 0.01 * np.arange(200.0), (4, 1))
    cls = np.full(ramp.shape, 50)
    res = line_residual(ramp, cls, 3, 5, 1)
    np.testing.assert_allclose(res[:, 3:-3], 0.0, atol=1e-9)
    noisy = ramp + rng.normal(0.0, 0.02, ramp.shape)
    assert np.median(line_residual(noisy, cls, 3, 5, 1)) == pytest.approx(0.02, rel=0.15)
    other = cls.copy()
    other[:, ::2] = 70  # every other pixel another class: 3-4 of 7 per class, fewer than 5
    assert np.isnan(line_residual(noisy, other, 3, 5, 1)).all()


def test_texture_holes_are_gaps_within_one_class():
    from research.simulation.texture import holes

    cls = np.array([[50, -1, -1, 50, -1, 70, -1, -1, -1, -1, 70, 70]])
    # 1-2: between two walls; 4: between two classes; 7-8: within 3 columns of the shrub both ways
    np.testing.assert_array_equal(holes(cls, reach=3), [[-1, 50, 50, -1, -1, -1, -1, 70, 70, -1, -1, -1]])


def test_simulate_campus_has_the_contacts_of_real_streets(scene):
    """Planting against walls and fences, shrubs against trunks, people and bikes leaning on walls,
    and parked cars bumper to bumper: gaps of 0-0.8 m, some touching, none overlapping."""
    kinds = {v.kind for v in scene.instances.values()}
    assert {"hedge_flush", "shrub_row", "trunk_shrub", "person_leaning", "bicycle_leaning", "rack"} <= kinds
    assert {"ivy", "hedge_gap"} & kinds
    static = scene.static
    cars = [iid for iid, v in scene.instances.items() if v.kind == "car" and not v.moving]
    gaps = []
    for iid in cars:
        mine = static.take(np.flatnonzero(static.instance == iid))
        near = np.flatnonzero((static.semantic == 10) & (static.instance != iid)
                              & (np.linalg.norm(static.center - mine.center[0], axis=1) < 8.0))
        if len(near):
            gaps.append(signed_distance(mine.corners().reshape(-1, 3), static.take(near)).min())
    gaps = np.asarray(gaps)
    assert (gaps < 0.85).mean() > 0.5 and (gaps < 0.06).sum() >= 2 and gaps.min() > -0.1
    for kind in ("hedge_flush", "trunk_shrub"):  # flush against a wall or fence, or a trunk
        host = (m.BUILDING, m.FENCE) if kind == "hedge_flush" else (m.TRUNK,)
        touching = 0
        for iid in [i for i, v in scene.instances.items() if v.kind == kind]:
            mine = static.take(np.flatnonzero(static.instance == iid))
            near = np.flatnonzero(np.isin(static.semantic, host)
                                  & (np.linalg.norm(static.center - mine.center[0], axis=1) < 40.0))
            touching += bool(len(near)) and surface_distance(mine.corners().reshape(-1, 3), static.take(near)).min() < 0.1
        assert touching >= 1, kind


def test_simulation_code_is_in_the_scene_cache_fingerprint(monkeypatch):
    """A change to any simulator module gives the experiments' cached scenes a new key."""
    from research.experiments import data

    before = data.code_fingerprint()
    real_read = Path.read_bytes
    for target in sorted((Path(data.__file__).resolve().parent.parent / "simulation").glob("*.py")):
        monkeypatch.setattr(Path, "read_bytes", lambda self, t=target: real_read(self) + (b"#" if self == t else b""))
        assert data.code_fingerprint() != before, target.name
    monkeypatch.undo()
    assert data.code_fingerprint() == before


def test_perception_code_is_in_the_scene_cache_fingerprint(monkeypatch):
    """The pipeline modules that shape samples count too (they live in another package)."""
    from research.experiments import data

    before = data.code_fingerprint()
    real_read = Path.read_bytes
    root = Path(data.__file__).resolve().parents[2]
    # every pipeline module counts, those the old list left out (readers, scan, pipeline) too
    io_module = sorted((root / "pipeline" / "io").glob("*.py"))[0]
    for target in (root / "pipeline" / "segmentation.py", root / "pipeline" / "processing.py", io_module,
                   root / "pipeline" / "scan.py", root / "pipeline" / "pipeline.py"):
        monkeypatch.setattr(Path, "read_bytes", lambda self, t=target: real_read(self) + (b"#" if self == t else b""))
        assert data.code_fingerprint() != before, target.name
    monkeypatch.undo()


def test_training_code_keeps_the_cached_scenes(monkeypatch):
    """A change to a module that only consumes samples (the training) leaves the scene key alone."""
    from research.experiments import data

    before = data.code_fingerprint()
    root = Path(data.__file__).resolve().parents[2]
    real_read = Path.read_bytes
    for name in sorted(data.SAMPLE_CONSUMERS):
        target = root / name
        assert target.is_file(), name
        monkeypatch.setattr(Path, "read_bytes", lambda self, t=target: real_read(self) + (b"#" if self == t else b""))
        assert data.code_fingerprint() == before, name
    monkeypatch.undo()


def test_no_scene_making_module_imports_a_sample_consumer():
    """The modules that make a scene's samples (simulator, readers, perception, the operator's
    review) never import the modules the scene fingerprint skips, so skipping them is safe."""
    import subprocess
    import sys

    from research.experiments import data

    root = Path(data.__file__).resolve().parents[2]
    consumers = sorted(n.removesuffix(".py").removesuffix("/__init__").replace("/", ".") for n in data.SAMPLE_CONSUMERS)
    code = ("import sys, research.experiments.data, research.simulation, pipeline.processing, pipeline.sequence, "
            "pipeline.pipeline, pipeline.io\n"
            f"print([m for m in {consumers!r} if m in sys.modules])")
    out = subprocess.run([sys.executable, "-c", code], cwd=root, capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]", out.stdout


def test_finetune_pretrained_models_are_keyed_by_the_training_code(monkeypatch):
    """A change to the training loop gives the fine-tuning experiment's pretrained models a new key."""
    from research.experiments import data
    from research.experiments.finetune import FinetuneExperimentConfig

    cfg = FinetuneExperimentConfig()
    before = cfg.key()
    target = Path(data.__file__).resolve().parents[2] / "pipeline" / "training" / "loop.py"
    real_read = Path.read_bytes
    monkeypatch.setattr(Path, "read_bytes", lambda self: real_read(self) + (b"#" if self == target else b""))
    assert cfg.key() != before
    monkeypatch.undo()
    assert cfg.key() == before
