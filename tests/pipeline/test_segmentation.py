from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from pipeline.config import GroundConfig, RangeImageConfig, SegmentationConfig
from pipeline.ground import estimate_ground
from pipeline.range_image import project
from pipeline.scan import Scan
from pipeline.segmentation import segment
from pipeline.sensors import PRESETS
from tests.pipeline.scans import add_box, flat_ground, scan_from_range_image

SENSOR = PRESETS["hdl32e"]
W = 360


def _scene() -> np.ndarray:
    rimg = flat_ground(SENSOR, W)
    add_box(rimg, slice(8, 20), slice(100, 110), 12.0)  # object A
    add_box(rimg, slice(8, 20), slice(111, 118), 18.0)  # object B, right next to A in the image
    add_box(rimg, slice(10, 16), slice(355, 360), 9.0)  # object C across the seam ...
    add_box(rimg, slice(10, 16), slice(0, 6), 9.0)  # ... continues at column 0
    return rimg


def _segment(scan: Scan, cfg: SegmentationConfig | None = None):
    img = project(scan, SENSOR, RangeImageConfig(width=W))
    g = estimate_ground(scan, img, GroundConfig(sensor_height=1.8))
    return img, g, segment(img, scan.points, g.ground, SENSOR, cfg)


def test_segmentation_ground_plane_is_ground():
    scan = scan_from_range_image(flat_ground(SENSOR, W), SENSOR)
    _, g, seg = _segment(scan)
    assert g.ground.mean() > 0.99
    assert seg.count == 0


def test_segmentation_splits_objects_at_range_jumps_and_wraps_the_seam():
    scan = scan_from_range_image(_scene(), SENSOR)
    img, g, seg = _segment(scan)
    r = img.point_range
    above = scan.points[:, 2] > -1.8 + 0.25  # clear of the ground band
    assert not g.ground[above].any()
    a, b, c = (np.isclose(r, d) & above for d in (12.0, 18.0, 9.0))
    for obj in (a, b, c):
        ids = np.unique(seg.point[obj])
        assert len(ids) == 1 and ids[0] >= 0  # one segment per object, across the seam for C
    assert len({int(seg.point[a][0]), int(seg.point[b][0]), int(seg.point[c][0])}) == 3


def test_segmentation_height_above_ground_of_object_points():
    scan = scan_from_range_image(_scene(), SENSOR)
    img, g, seg = _segment(scan)
    obj = np.isclose(img.point_range, 12.0) & (scan.points[:, 2] > -1.8 + 0.25)
    expected = scan.points[obj, 2] + 1.8
    # cells right under an object see only its foot (the ground behind is occluded): 0.1 m slack
    assert np.abs(g.height[obj] - expected).max() < 0.1


@settings(max_examples=15, deadline=None)
@given(shift=st.integers(0, W - 1))
def test_segmentation_labels_are_invariant_to_column_rotation(shift):
    rimg = _scene()
    base = scan_from_range_image(rimg, SENSOR)
    rolled = scan_from_range_image(np.roll(rimg, shift, axis=1), SENSOR)
    _, _, s0 = _segment(base)
    _, _, s1 = _segment(rolled)
    # same partition: map each scan's points to (row, range) groups -> compare partitions via pixels
    img0 = project(base, SENSOR, RangeImageConfig(width=W))
    img1 = project(rolled, SENSOR, RangeImageConfig(width=W))
    lab0 = np.full((SENSOR.n_rings, W), -1)
    lab1 = np.full((SENSOR.n_rings, W), -1)
    lab0[img0.row, img0.col] = s0.point
    lab1[img1.row, img1.col] = s1.point
    lab1 = np.roll(lab1, -shift, axis=1)
    assert ((lab0 >= 0) == (lab1 >= 0)).all()
    m = lab0 >= 0
    pairs = np.unique(np.stack([lab0[m], lab1[m]], axis=1), axis=0)
    # a bijection between segment ids
    assert len(np.unique(pairs[:, 0])) == len(pairs) == len(np.unique(pairs[:, 1]))


def _dominant(seg, mask: np.ndarray) -> int:
    ids, counts = np.unique(seg.point[mask], return_counts=True)
    return int(ids[np.argmax(counts)])


def test_segmentation_angle_criterion_cuts_a_surface_seen_at_a_grazing_angle():
    rimg = flat_ground(SENSOR, W)
    rimg[4:11, 100:130] = 10.0 + 0.2 * np.arange(30)  # a wall receding 0.2 m per 1 deg column
    scan = scan_from_range_image(rimg, SENSOR)
    wall = (scan.ring >= 4) & (scan.ring < 11) & (np.linalg.norm(scan.points, axis=1) < 17.0)
    _, _, plain = _segment(scan, SegmentationConfig(angle_threshold_deg=0.0))
    _, _, strict = _segment(scan, SegmentationConfig(angle_threshold_deg=60.0))
    assert len(np.unique(plain.point[wall])) == 1
    assert len(np.unique(strict.point[wall])) > 10


def _hedge_on_wall(patch_rows: slice, patch_cols: slice, scatter: float) -> tuple[Scan, np.ndarray, np.ndarray]:
    """A smooth wall at 12 m with a patch of scattered returns (foliage) flush in front of it."""
    rimg = flat_ground(SENSOR, W)
    add_box(rimg, slice(2, 14), slice(80, 160), 12.0)
    noise = np.random.default_rng(0).normal(0.0, scatter, (patch_rows.stop - patch_rows.start,
                                                           patch_cols.stop - patch_cols.start))
    rimg[patch_rows, patch_cols] = 12.0 - np.abs(noise)
    scan = scan_from_range_image(rimg, SENSOR)
    rows, cols = scan.ring, np.round(np.degrees(np.pi - np.arctan2(scan.points[:, 1], scan.points[:, 0])) - 0.5)
    in_patch = (rows >= patch_rows.start) & (rows < patch_rows.stop) & (cols >= patch_cols.start) & (cols < patch_cols.stop)
    in_wall = (rows >= 2) & (rows < 14) & (cols >= 80) & (cols < 160) & ~in_patch
    return scan, in_patch, in_wall


def test_segmentation_separates_foliage_flush_against_a_wall():
    scan, hedge, wall = _hedge_on_wall(slice(6, 14), slice(100, 130), scatter=0.12)
    _, _, seg = _segment(scan)
    assert _dominant(seg, hedge) != _dominant(seg, wall)
    _, _, no_texture = _segment(scan, SegmentationConfig(texture_base=0.0, texture_slope=0.0))
    assert _dominant(no_texture, hedge) == _dominant(no_texture, wall)


def test_segmentation_merges_a_small_rough_patch_back_into_its_object():
    scan, patch, wall = _hedge_on_wall(slice(6, 12), slice(110, 122), scatter=0.12)  # 72 pixels
    _, _, seg = _segment(scan)
    assert _dominant(seg, patch) == _dominant(seg, wall)
    _, _, unmerged = _segment(scan, SegmentationConfig(merge_pixels=0))
    assert _dominant(unmerged, patch) != _dominant(unmerged, wall)


def _smooth_under_rough(rows: slice, cols: slice) -> tuple[Scan, np.ndarray, np.ndarray]:
    """A mass of scattered returns (a crown, or a car's glass) at 12 m over rows 2-8, and a
    smooth piece right under it."""
    rimg = flat_ground(SENSOR, W)
    noise = np.random.default_rng(1).normal(0.0, 0.12, (7, 30))
    rimg[2:9, 100:130] = 12.0 - np.abs(noise)
    add_box(rimg, rows, cols, 12.0)
    scan = scan_from_range_image(rimg, SENSOR)
    cols_of = np.round(np.degrees(np.pi - np.arctan2(scan.points[:, 1], scan.points[:, 0])) - 0.5)
    rough = (scan.ring >= 2) & (scan.ring < 9) & (cols_of >= 100) & (cols_of < 130)
    smooth = (scan.ring >= rows.start) & (scan.ring < rows.stop) & (cols_of >= cols.start) & (cols_of < cols.stop)
    return scan, rough, smooth & (scan.points[:, 2] > -1.8 + 0.25)


def test_segmentation_keeps_a_trunk_apart_from_the_crown_above_it():
    # 3 columns (3 deg) wide and 8 beams (~10 deg) tall: 24 pixels, under merge_pixels
    scan, crown, trunk = _smooth_under_rough(slice(9, 17), slice(113, 116))
    _, _, seg = _segment(scan)
    assert _dominant(seg, trunk) >= 0 and _dominant(seg, trunk) != _dominant(seg, crown)


def test_segmentation_merges_a_wide_smooth_piece_into_the_rough_mass_above_it():
    # 20 deg wide, ~5 deg tall (a car's door under its glass): it goes back to its object
    scan, glass, door = _smooth_under_rough(slice(9, 13), slice(105, 125))
    _, _, seg = _segment(scan)
    assert _dominant(seg, door) == _dominant(seg, glass)


def test_segmentation_steps_over_a_nearer_occluder():
    rimg = flat_ground(SENSOR, W)
    add_box(rimg, slice(6, 14), slice(100, 130), 12.0)  # a car ...
    add_box(rimg, slice(0, 16), slice(113, 116), 8.0)  # ... behind a pole
    scan = scan_from_range_image(rimg, SENSOR)
    car = np.isclose(np.linalg.norm(scan.points, axis=1), 12.0, atol=1e-3) & (scan.points[:, 2] > -1.55)
    assert len(np.unique(_segment(scan)[2].point[car])) == 1
    assert len(np.unique(_segment(scan, SegmentationConfig(occluder_pixels=0))[2].point[car])) == 2


def test_segmentation_takes_the_feet_of_an_object_back_from_the_ground_band():
    rimg = flat_ground(SENSOR, W)
    add_box(rimg, slice(4, 15), slice(100, 110), 12.0)  # down to 0.1 m above the ground
    scan = scan_from_range_image(rimg, SENSOR)
    box = np.isclose(np.linalg.norm(scan.points, axis=1), 12.0, atol=1e-3)
    feet = box & (scan.points[:, 2] < -1.8 + 0.2)
    assert feet.any()
    # rings 0.28 m apart at 12 m: the foot lies more than the default 0.25 m below the next pixel
    _, g, seg = _segment(scan, SegmentationConfig(foot_height=0.35))
    assert len(np.unique(seg.point[box])) == 1 and (seg.point[box] >= 0).all()
    _, _, cut = _segment(scan, SegmentationConfig(foot_height=0.0))
    assert (cut.point[feet] == -1).all()
    # the road in front of it stays ground
    road = ~box & (scan.points[:, 2] < -1.7)
    assert (seg.point[road] == -1).all()


def test_segmentation_too_few_points_gives_no_segments():
    pts = np.array([[5.0, 0.0, 0.0], [5.0, 0.1, 0.0]], np.float32)
    scan = Scan(pts, np.ones(2, np.float32), np.array([10, 10], np.int16))
    _, _, seg = _segment(scan)
    assert seg.count == 0 and (seg.point == -1).all()


def test_segmentation_bridges_one_empty_column_but_not_a_return():
    rimg = flat_ground(SENSOR, W)
    add_box(rimg, slice(8, 14), slice(100, 106), 12.0)
    add_box(rimg, slice(8, 14), slice(107, 113), 12.0)
    rimg[:14, 106] = 0.0  # a column without any return (dropout) above the ground rows
    scan = scan_from_range_image(rimg, SENSOR)
    above = scan.points[:, 2] > -1.8 + 0.25
    obj = np.isclose(np.linalg.norm(scan.points, axis=1), 12.0, atol=1e-3) & above
    _, _, bridged = _segment(scan)
    _, _, strict = _segment(scan, SegmentationConfig(bridge_horizontal=0, merge_pixels=0))
    assert len(np.unique(bridged.point[obj])) == 1
    assert len(np.unique(strict.point[obj])) == 2
    # the same gap holding a far return (background) is not stepped over
    rimg[8:14, 106] = 40.0
    scan = scan_from_range_image(rimg, SENSOR)
    obj = np.isclose(np.linalg.norm(scan.points, axis=1), 12.0, atol=1e-3) & (scan.points[:, 2] > -1.55)
    _, _, seg = _segment(scan)
    assert len(np.unique(seg.point[obj])) == 2


def _two_boxes_with_gap(gap: int, vertical: bool) -> tuple[Scan, np.ndarray]:
    """Two boxes at 12 m separated by `gap` empty columns (or rows when `vertical`)."""
    rimg = flat_ground(SENSOR, W)
    if vertical:
        add_box(rimg, slice(2, 6), slice(100, 110), 12.0)
        add_box(rimg, slice(6 + gap, 12 + gap), slice(100, 110), 12.0)
        rimg[6 : 6 + gap, 100:110] = 0.0
    else:
        add_box(rimg, slice(8, 14), slice(100, 106), 12.0)
        add_box(rimg, slice(8, 14), slice(106 + gap, 112 + gap), 12.0)
        rimg[:14, 106 : 106 + gap] = 0.0
    scan = scan_from_range_image(rimg, SENSOR)
    obj = np.isclose(np.linalg.norm(scan.points, axis=1), 12.0, atol=1e-3) & (scan.points[:, 2] > -1.8 + 0.25)
    return scan, obj


def test_segmentation_bridges_up_to_bridge_pixels_empty_pixels():
    for vertical in (False, True):
        for gap in (2, 4):
            scan, obj = _two_boxes_with_gap(gap, vertical)
            for limit in (1, 2, 4, 6):
                key = "bridge_vertical" if vertical else "bridge_horizontal"
                cfg = SegmentationConfig(**{key: limit}, merge_pixels=0, occluder_pixels=0)
                _, _, seg = _segment(scan, cfg)
                assert (len(np.unique(seg.point[obj])) == 1) == (gap <= limit), (vertical, gap, limit)


@settings(max_examples=60, deadline=None)
@given(
    h=st.integers(1, 8),
    w=st.integers(3, 24),
    seed=st.integers(0, 2**31 - 1),
    ok_share=st.floats(0.2, 1.0),
    join_share=st.floats(0.0, 1.0),
)
def test_label_components_match_graph_components(h, w, seed, ok_share, join_share):
    """The union-find over row runs gives the connected components of the join maps (one- and
    two-pixel joins, across the seam), numbered in raster order of their first pixel."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    from pipeline.segment_merge import _label_components

    rng = np.random.default_rng(seed)
    ok = rng.random((h, w)) < ok_share
    empty = ~ok & (rng.random((h, w)) < 0.5)
    right = np.zeros((h, w), np.uint8)
    down = np.zeros((h, w), np.uint8)
    edges = []
    for r in range(h):
        for c in range(w):
            if not ok[r, c]:
                continue
            c1, step = (c + 1) % w, 1
            if empty[r, c1]:
                c1, step = (c + 2) % w, 2
            if ok[r, c1] and c1 != c and rng.random() < join_share:
                right[r, c] = step
                edges.append((r * w + c, r * w + c1))
            r1, step = r + 1, 1
            if r1 < h and empty[r1, c]:
                r1, step = r + 2, 2
            if r1 < h and ok[r1, c] and rng.random() < join_share:
                down[r, c] = step
                edges.append((r * w + c, r1 * w + c))
    labels, sizes, count = _label_components(ok, right, down)
    e = np.array(edges, dtype=np.int64).reshape(-1, 2)
    graph = coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(h * w, h * w))
    _, comp = connected_components(graph, directed=False)
    flat_ok = ok.ravel()
    # renumber the reference components in raster order of their first ok pixel
    order = {}
    ref = np.full(h * w, -1)
    for p in np.flatnonzero(flat_ok):
        ref[p] = order.setdefault(comp[p], len(order))
    assert count == len(order)
    assert np.array_equal(labels.ravel(), ref)
    assert np.array_equal(sizes, np.bincount(ref[flat_ok], minlength=count))
