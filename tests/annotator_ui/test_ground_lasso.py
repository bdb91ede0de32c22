"""The ground lasso (issue 35): clicks become vertices on the frame's ground, Close & label stores
the polygon with the chosen class, undo deletes the newest region, and the frame's ground points
inside stored regions are drawn in the region's class colour (only those: the service's rule),
in this tab and, through the change feed, in the others."""

from __future__ import annotations

from types import SimpleNamespace

import httpx
import numpy as np
import pytest

from annotator_ui.colours import fade
from annotator_ui.geometry import world_to_lidar
from annotator_ui.ground_regions import (
    RegionClasses,
    StoredRegion,
    click_on_ground,
    ground_map,
    labelable,
    paint_regions,
)
from pipeline.classes import CLASS_COLOURS
from pipeline.propagation import to_world
from pipeline.regions import points_in_polygon
from tests.annotator_ui.test_viewer import wait_until

CLASSES = RegionClasses.from_label_set([{"name": n, "colour": CLASS_COLOURS[n], "ground": n == "ground"}
                                        for n in CLASS_COLOURS])


def _square(x0: float, y0: float, x1: float, y1: float) -> np.ndarray:
    return np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]], np.float64)


# ---------------------------------------------------------------------------- geometry, no service
def test_ground_click_meets_the_local_ground_under_the_click():
    # flat ground at -1.7 m around the sensor, a ramp up to -0.7 m between x = 18 and 22 m
    xs, ys = np.meshgrid(np.arange(-30, 30, 0.5), np.arange(-10, 10, 0.5))
    pts = np.column_stack([xs.ravel(), ys.ravel(), np.where((xs >= 18) & (xs <= 22), -0.7, -1.7).ravel()])
    ground = np.ones(len(pts), bool)
    origin = np.array([0.0, 0.0, 5.0])
    near = click_on_ground(pts, ground, origin, np.array([10.0, 2.0, -1.7]) - origin)
    assert near is not None and np.allclose(near, [10.0, 2.0, -1.7], atol=1e-6)
    far = click_on_ground(pts, ground, origin, np.array([20.0, 0.0, -0.7]) - origin)
    assert far is not None and abs(far[2] + 0.7) < 1e-6 and abs(far[0] - 20.0) < 1e-6  # the ramp's height, not -1.7


def test_ground_click_that_does_not_come_down_or_has_no_ground_picks_nothing():
    pts = np.array([[5.0, 0, -1.7], [6, 0, -1.7], [7, 0, -1.7]])
    assert click_on_ground(pts, np.ones(3, bool), np.zeros(3), np.array([1.0, 0, 0.2])) is None  # above the horizon
    assert click_on_ground(pts, np.zeros(3, bool), np.zeros(3), np.array([1.0, 0, -0.2])) is None  # no ground


def test_ground_labelable_follows_the_services_rule():
    ground = np.array([True, True, True, False, False, True])
    track = np.array([0, 5, 6, 7, 0, 8])
    tracks = {5: {"status": "accepted", "label": "car", "keep_start": 0, "keep_end": 9},  # decided: keeps its class
              6: {"status": "pending", "label": None, "keep_start": 0, "keep_end": 9},
              7: {"status": "discarded", "label": None, "keep_start": 0, "keep_end": 9},  # no object: ground
              8: {"status": "accepted", "label": "car", "keep_start": 3, "keep_end": 9}}  # decided, not in frame 1
    assert labelable(ground, track, tracks, 1).tolist() == [True, False, True, True, False, True]
    assert labelable(ground, track, None, 1).tolist() == [True, False, False, False, False, False]  # track mode


def test_ground_paint_colours_eligible_points_inside_the_newest_region_only():
    xy = np.array([[1.0, 1.0, 0.0], [3.0, 1.0, 0.0], [1.0, 1.0, 0.0], [9.0, 9.0, 0.0]])
    eligible = np.array([True, True, False, True])
    colours = np.full((4, 3), 7, np.uint8)
    old = StoredRegion(1, "bush", _square(0, 0, 4, 2))
    new = StoredRegion(2, "building", _square(2, 0, 4, 2))
    out = paint_regions(colours, xy, eligible, [old, new], CLASSES)
    assert out[0].tolist() == list(CLASS_COLOURS["bush"]) and out[1].tolist() == list(CLASS_COLOURS["building"])
    assert out[2].tolist() == [7, 7, 7] and out[3].tolist() == [7, 7, 7]  # not ground / outside
    assert paint_regions(colours, xy, eligible, [StoredRegion(3, "bush", _square(20, 20, 21, 21))], CLASSES) is colours


def test_region_with_heights_paints_every_point_of_its_prism_and_no_other():
    # a hedge (z 0.5-2 m) over a fence post of a reviewed track and a road point, inside the polygon
    world = np.array([[1.0, 1.0, 1.0], [1.5, 1.0, 1.8], [1.0, 1.5, -0.1], [1.0, 1.0, 2.5], [9.0, 9.0, 1.0]])
    eligible = np.array([False, False, True, False, False])  # the ground rule: only the road point
    hedge = StoredRegion(4, "bush", _square(0, 0, 4, 4), (0.5, 2.0))
    colours = np.full((5, 3), 7, np.uint8)
    out = paint_regions(colours, world, eligible, [hedge], CLASSES)
    assert [tuple(c) for c in out] == [tuple(CLASS_COLOURS["bush"])] * 2 + [(7, 7, 7)] * 3  # between its heights only
    # in the track mode a region with heights colours only points of no track
    out = paint_regions(colours, world, eligible, [hedge], CLASSES, any_eligible=np.array([False, True, True, True, True]))
    assert out[0].tolist() == [7, 7, 7] and out[1].tolist() == list(CLASS_COLOURS["bush"])
    # a newer region of ground points over it takes the ground points only
    road = StoredRegion(5, "ground", _square(0, 0, 4, 4))
    out = paint_regions(colours, world, eligible, [hedge, road], CLASSES)
    assert out[0].tolist() == list(CLASS_COLOURS["bush"]) and out[2].tolist() == list(CLASS_COLOURS["ground"])


def test_ground_region_classes_put_ground_classes_first():
    classes = RegionClasses.from_label_set([{"name": "car", "colour": [1, 2, 3], "ground": False},
                                            {"name": "road", "colour": [4, 5, 6], "ground": True}])
    assert classes.names == ("road", "car") and classes.colours["road"].tolist() == [4, 5, 6]


def test_ground_map_joins_every_frames_ground_in_the_world_one_point_per_cell():
    xs, ys = np.meshgrid(np.arange(0, 10, 0.1), np.arange(0, 4, 0.1))
    grid = np.column_stack([xs.ravel(), ys.ravel(), np.full(xs.size, -1.7)])
    points = np.vstack([grid, [[3.0, 1.0, 0.5]]])  # and one point that is not ground
    ground = np.r_[np.ones(len(grid), bool), False]
    moved = np.eye(4)
    moved[:3, 3] = [10.0, 0.0, 0.2]  # the second frame 10 m on, its sensor 0.2 m higher
    world = ground_map([(points, ground, np.eye(4)), (points, ground, moved)], cell=0.5)
    assert world[:, 0].min() < 0.5 and world[:, 0].max() >= 19.5  # both frames' ground
    cells = np.floor(world[:, :2] / 0.5).astype(np.int64)
    assert len(np.unique(cells, axis=0)) == len(world) == 40 * 8  # one point per 0.5 m cell of 20 x 4 m
    assert np.allclose(world[world[:, 0] >= 10, 2], -1.5) and (world[:, 2] < 0).all()  # posed; no point above
    assert ground_map([]).shape == (0, 3)


# ---------------------------------------------------------------------------- in a connected tab
@pytest.fixture
def lasso_tab(tab, live_api):
    """The tab; the regions it drew are undone after the test (the service is shared)."""
    yield tab
    admin = {"Authorization": f"Bearer {live_api.admin_token}"}
    for r in httpx.get(f"{live_api.url}/api/v1/sequences/{live_api.sequence_id}/ground-regions", headers=admin).json():
        httpx.delete(f"{live_api.url}/api/v1/ground-regions/{r['id']}", headers=admin)  # the service is shared


def _click(tab, target: np.ndarray) -> None:
    origin = target + np.array([-6.0, -4.0, 9.0])  # a camera above and behind the spot
    tab._on_click(SimpleNamespace(ray_origin=tuple(origin), ray_direction=tuple(target - origin)))


def _ground_patch(tab, half: float = 3.0) -> np.ndarray:
    """(4, 3) lidar corners of a square (2 half wide) around the frame's densest ground, on that ground."""
    view = tab.ground_view()
    g = view.points[view.ground]
    centre = np.median(g[np.linalg.norm(g[:, :2], axis=1) < 15], axis=0)
    corners = centre[None, :2] + half * np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]], np.float64)
    return np.column_stack([corners, np.full(4, np.median(g[:, 2]))])


def _expected_inside(tab, polygon_world: np.ndarray) -> np.ndarray:
    view, keep = tab.ground_view(), tab.scene._cloud_keep
    inside = points_in_polygon(to_world(view.points[keep], view.T_world_lidar)[:, :2], polygon_world)
    return inside & view.ground[keep] & (tab.scene.frame_tracks[keep] == 0)  # the track mode's rule


def test_ground_lasso_draws_labels_colours_and_undoes(lasso_tab, live_api):
    tab = lasso_tab
    panel, scene = tab.ground, tab.scene
    wait_until(lambda: panel.sequence_id == live_api.sequence_id)
    before = scene._cloud_colours.copy()
    corners = _ground_patch(tab)
    panel.gui_draw.value = True
    for c in corners:
        _click(tab, c)
    T = tab.ground_view().T_world_lidar
    want = (np.column_stack([corners, np.ones(4)]) @ T.T)[:, :2]
    assert len(panel.draft) == 4 and np.allclose(np.array(panel.draft)[:, :2], want, atol=0.3)
    tab.headless.wait_for(lambda m: m.type == "LineSegmentsMessage" and m.name == "/ground/draft")
    assert tab.session.track_id is not None  # the clicks drew; they opened no other track
    panel.gui_class.value = "building"
    region = panel.close_and_label()
    assert region is not None and panel.draft == []
    api = httpx.get(f"{live_api.url}/api/v1/sequences/{live_api.sequence_id}/ground-regions",
                    headers={"Authorization": f"Bearer {live_api.admin_token}"}).json()
    assert [(r["id"], r["class_name"]) for r in api] == [(region["id"], "building")]
    stored = np.array(api[0]["polygon"])
    assert np.allclose(stored, want, atol=0.3)

    inside = _expected_inside(tab, stored)
    assert inside.sum() >= 10, "the patch holds the frame's ground"
    wait_until(lambda: not np.array_equal(scene._cloud_colours, before))
    shown = scene._cloud_colours
    building = fade(np.array([CLASS_COLOURS["building"]], np.uint8), np.zeros(1, bool))[0]
    assert (shown[inside] == building).all()
    assert np.array_equal(shown[~inside], before[~inside])  # outside, and points that are not ground, keep theirs
    tab.headless.wait_for(lambda m: m.type == "LineSegmentsMessage" and m.name == "/ground/regions")

    gone = panel.undo()
    assert gone is not None and gone["id"] == region["id"] and panel.regions == ()
    wait_until(lambda: np.array_equal(scene._cloud_colours, before))
    assert panel.undo() is None  # nothing left to undo


def test_region_between_heights_stores_them_above_its_ground_and_paints_its_prism(lasso_tab, live_api):
    tab = lasso_tab
    panel, scene = tab.ground, tab.scene
    wait_until(lambda: panel.sequence_id == live_api.sequence_id)
    before = scene._cloud_colours.copy()
    panel.gui_draw.value = True
    for c in _ground_patch(tab, half=15.0):
        _click(tab, c)
    assert len(panel.draft) == 4
    ground_z = float(np.median(np.array(panel.draft)[:, 2]))
    panel.gui_prism.value, panel.gui_low.value, panel.gui_high.value = True, 0.3, 2.5
    panel.gui_class.value = "bush"
    region = panel.close_and_label()
    assert region is not None
    assert region["z_min"] == pytest.approx(ground_z + 0.3) and region["z_max"] == pytest.approx(ground_z + 2.5)
    view, keep = tab.ground_view(), scene._cloud_keep
    world = to_world(view.points[keep], view.T_world_lidar)
    inside = (points_in_polygon(world[:, :2], np.array(region["polygon"])) & (world[:, 2] >= region["z_min"])
              & (world[:, 2] <= region["z_max"]) & (scene.frame_tracks[keep] == 0))  # the track mode: no track's points
    assert (inside & ~view.ground[keep]).sum() >= 10, "the prism holds points that are not ground"
    wait_until(lambda: not np.array_equal(scene._cloud_colours, before))
    bush = fade(np.array([CLASS_COLOURS["bush"]], np.uint8), np.zeros(1, bool))[0]
    assert (scene._cloud_colours[inside] == bush).all()
    assert np.array_equal(scene._cloud_colours[~inside], before[~inside])
    assert "between" in panel.gui_regions.content or "z " in panel.gui_regions.content


def test_ground_regions_of_another_operator_reach_the_tab_through_the_change_feed(lasso_tab, live_api):
    tab = lasso_tab
    wait_until(lambda: tab.ground.sequence_id == live_api.sequence_id)
    before = tab.scene._cloud_colours.copy()
    admin = {"Authorization": f"Bearer {live_api.admin_token}"}
    everywhere = [[-1e5, -1e5], [1e5, -1e5], [1e5, 1e5], [-1e5, 1e5]]
    r = httpx.post(f"{live_api.url}/api/v1/sequences/{live_api.sequence_id}/ground-regions",
                   json={"class_name": "bush", "polygon": everywhere}, headers=admin)
    assert r.status_code == 200, r.text
    wait_until(lambda: [g.id for g in tab.ground.regions] == [r.json()["id"]])
    inside = _expected_inside(tab, np.array(everywhere, np.float64))
    wait_until(lambda: not np.array_equal(tab.scene._cloud_colours, before))
    bush = fade(np.array([CLASS_COLOURS["bush"]], np.uint8), np.zeros(1, bool))[0]
    assert inside.any() and (tab.scene._cloud_colours[inside] == bush).all()
    assert httpx.delete(f"{live_api.url}/api/v1/ground-regions/{r.json()['id']}", headers=admin).status_code == 200
    wait_until(lambda: tab.ground.regions == ())
    wait_until(lambda: np.array_equal(tab.scene._cloud_colours, before))


def test_ground_every_frame_shows_the_route_from_above_and_takes_clicks_beyond_the_frame(lasso_tab, live_api):
    from scipy.spatial import cKDTree

    tab = lasso_tab
    panel = tab.ground
    wait_until(lambda: panel.sequence_id == live_api.sequence_id)
    since = len(tab.headless.messages)
    panel.gui_every.value = True
    panel.show_every_frame()  # what ticking the box runs, in the background
    tab.headless.wait_for(lambda m: m.type == "PointCloudMessage" and m.name == "/ground/map/points", since)
    view = tab.ground_view()
    world = panel.map_world
    frame_xy = to_world(view.points[view.ground], view.T_world_lidar)[:, :2]
    far = cKDTree(frame_xy).query(world[:, :2])[0]
    alone = ground_map([(view.points, view.ground, view.T_world_lidar)])
    assert len(world) > len(alone) and far.max() > 1.0, "the map holds ground the frame shown does not reach"
    assert panel.gui_every.value and len(world) == len(np.unique(np.floor(world[:, :2] / 0.25), axis=0))

    # a clicked vertex sits on the map's ground, not on the frame's: a terrace 2 m up, beyond the
    # frame's ground (the frame's height would put the vertex 1.6 m further along the ray)
    centre = world[np.argmax(far)] + [0.0, 0.0, 2.0]
    xs, ys = np.meshgrid(np.arange(-2, 2.01, 0.25), np.arange(-2, 2.01, 0.25))
    terrace = centre + np.column_stack([xs.ravel(), ys.ravel(), np.zeros(xs.size)])
    panel.map_world = np.vstack([world, terrace])
    panel.gui_draw.value = True
    _click(tab, world_to_lidar(centre[None], view.T_world_lidar)[0])
    assert len(panel.draft) == 1 and np.allclose(panel.draft[0], centre, atol=0.05)
    for dx, dy in ((4, 0), (4, 4)):
        _click(tab, world_to_lidar(centre[None] + [dx, dy, 0], view.T_world_lidar)[0])
    assert len(panel.draft) == 3
    since = len(tab.headless.messages)
    region = panel.close_and_label()
    assert region is not None
    # the map is drawn again in the region's colours
    tab.headless.wait_for(lambda m: m.type == "PointCloudMessage" and m.name == "/ground/map/points", since)

    panel.gui_every.value = False
    panel.show_every_frame()
    tab.headless.wait_for(lambda m: m.type == "RemoveSceneNodeMessage" and m.name == "/ground/map", since)
    assert panel._map_of(live_api.sequence_id) is None  # clicks land on the frame's ground again


def test_alt_drag_labels_every_point_of_the_frame_shown_inside_the_rectangle_in_that_frame_only(lasso_tab, live_api):
    from annotator_ui.geometry import clip_from_scene, matrix_wxyz
    from pipeline.regions import ScreenLasso

    tab = lasso_tab
    panel, scene = tab.ground, tab.scene
    wait_until(lambda: panel.sequence_id == live_api.sequence_id)
    before = scene._cloud_colours.copy()
    # a camera at the sensor looking along its x axis (OpenCV axes: x right = -y, y down = -z, z forward = x)
    R = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
    cam = SimpleNamespace(position=(0.0, 0.0, 0.0), wxyz=tuple(matrix_wxyz(R)), fov=1.2, aspect=1.5)
    panel.gui_class.value = "building"
    panel._on_rect(SimpleNamespace(client=SimpleNamespace(camera=cam), screen_min=(0.3, 0.3), screen_max=(0.7, 0.9)))
    admin = {"Authorization": f"Bearer {live_api.admin_token}"}
    api = httpx.get(f"{live_api.url}/api/v1/sequences/{live_api.sequence_id}/ground-regions", headers=admin).json()
    assert len(api) == 1 and api[0]["class_name"] == "building"
    assert api[0]["frame_index"] == tab.session.frame_index and len(api[0]["clip_from_world"]) == 16
    wait_until(lambda: f"frame {tab.session.frame_index} (its view)" in panel.gui_regions.content)
    view, keep = tab.ground_view(), scene._cloud_keep
    clip = clip_from_scene(np.zeros(3), np.asarray(cam.wxyz), cam.fov, cam.aspect)
    lasso = ScreenLasso(np.array(api[0]["polygon"]), clip)
    inside = lasso.contains(view.points[keep].astype(np.float64)) & (scene.frame_tracks[keep] == 0)  # the track mode
    assert inside.sum() >= 10 and (~inside).sum() >= 10
    building = fade(np.array([CLASS_COLOURS["building"]], np.uint8), np.zeros(1, bool))[0]
    wait_until(lambda: (scene._cloud_colours[inside] == building).all())
    assert np.array_equal(scene._cloud_colours[~inside], before[~inside])
    # stored in the world: the same points from the world's side, and only in this frame
    rule = StoredRegion.from_public(api[0]).rule()
    world = to_world(view.points[keep], view.T_world_lidar)
    assert np.array_equal(rule.labels(world, None, tab.session.frame_index) & (scene.frame_tracks[keep] == 0), inside)
    assert not rule.labels(world, None, tab.session.frame_index + 1).any()
    assert panel.undo() is not None
    wait_until(lambda: np.array_equal(scene._cloud_colours, before))
    # with a depth from 2 to 12 m the points nearer and farther stay out
    panel.gui_depth.value = (2.0, 12.0)
    panel._on_rect(SimpleNamespace(client=SimpleNamespace(camera=cam), screen_min=(0.3, 0.3), screen_max=(0.7, 0.9)))
    api = httpx.get(f"{live_api.url}/api/v1/sequences/{live_api.sequence_id}/ground-regions", headers=admin).json()
    held = StoredRegion.from_public(api[0]).rule().labels(world, None, tab.session.frame_index)
    depth = view.points[keep][:, 0]  # the camera looks along the sensor's x axis
    assert held.any() and (depth[held] >= 2.0 - 1e-6).all() and (depth[held] <= 12.0 + 1e-6).all()
    assert (inside & ~held).any()
    panel.gui_depth.value = (0.0, 0.0)
