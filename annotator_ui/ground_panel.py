"""The Ground tab: the top view's lasso (issue 35). The operator picks a class, ticks *Draw* and
clicks the ground in the 3D view; each click adds a vertex where the click ray meets the ground
of the frame shown (annotator_ui.ground_regions.click_on_ground), or, with *Every frame's
ground* ticked, the ground of all the sequence's frames seen from above (`ground_map`: a lawn
or a sidewalk along the whole route in one view, one polygon for it). *Close & label* stores the
polygon (world x, y) as a ground region of the sequence: the service then gives the ground points
inside it that class in every frame. With *Every point between heights* ticked it gives the class
to every point inside the prism from *From* to *To* metres above the polygon's ground (the median
height of its vertices), a reviewed track's points too: a hedge, or a fence grown into one, in one
action. Alt + drag on the canvas labels every point of the frame shown inside the rectangle with
the chosen class, in that frame only (a lasso in the frame's view: the fence boards inside a
hedge, the last leaves among the lawn), between *Alt + drag depth* From and To metres from the
camera when To is the larger. *Undo last region* deletes the sequence's newest region.

Scene (the shown frame's lidar frame, like every node of the tab):
  /ground/draft    the polygon being drawn: its edges (yellow) and the closing edge (grey)
  /ground/nodes    its vertices
  /ground/regions  the outlines of the stored regions of every frame and of the frame shown, in
                   their class colours, at the frame's ground height (a region with heights: at
                   its low and high); a lasso in a frame's view has no outline on the ground
  /ground/map      every frame's ground (world points under a frame node placed at the world's
                   pose in the frame shown, so a frame step moves it without sending it again),
                   in the stored regions' colours
The stored regions also colour the frame's ground points (SceneView asks `paint`), so what the
tab shows is what the exports write; the tab re-reads them after each of its edits and when the
change feed says another tab or operator changed them.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import Any

import numpy as np
import viser

from annotator_ui.client import ApiClient, ApiError, FramePayload
from annotator_ui.colours import fade
from annotator_ui.geometry import (
    clip_from_scene,
    matrix_wxyz,
    polyline_segments,
    rect_polygon_ndc,
    world_to_lidar,
)
from annotator_ui.ground_regions import (
    GroundView,
    RegionClasses,
    StoredRegion,
    click_on_ground,
    ground_height,
    labelable,
    paint_regions,
)
from pipeline.propagation import to_world
from pipeline.regions import with_depth_planes

MAP_GROUND = np.array([150, 140, 120], np.uint8)  # the map's ground that no region labels
DRAFT = (255, 215, 0)
CLOSING = (150, 150, 150)
MAX_VERTICES = 1000  # the service's limit


def _segments(vertices: np.ndarray, closed: bool) -> np.ndarray:
    """(K, 3) vertices -> (S, 2, 3) edges (the closing edge too when `closed`)."""
    return polyline_segments(np.concatenate([vertices, vertices[:1]]) if closed else vertices)


def _keys(regions: tuple[StoredRegion, ...]) -> list[tuple[int, str, bytes, tuple[float, float] | None]]:
    """What tells two region lists apart: ids, and what a region labels with what."""
    return [(r.id, r.class_name, r.polygon.tobytes(), r.heights, r.frame_index) for r in regions]


class GroundPanel:
    """Draw, store and undo ground regions; colour the ground points they label."""

    def __init__(self, gui: viser.GuiApi, scene: viser.SceneApi, api: ApiClient,
                 notify: Callable[[str, str, str], None], view: Callable[[], GroundView | None],
                 recolour: Callable[[], None], load_map: Callable[[int], np.ndarray],
                 look_down: Callable[[np.ndarray], None], later: Callable[[Callable[[], None]], None]) -> None:
        self.scene, self.api, self.notify, self.view, self.recolour = scene, api, notify, view, recolour
        self.load_map, self.look_down, self.later = load_map, look_down, later
        gui.add_markdown("Tick the Draw box, click the ground around an area (a lawn, a sidewalk), then "
                         "close and label it: its ground points take the class in every frame. With *Every "
                         "point between heights*, every point from From to To above it does (a hedge, a fence). "
                         "Alt + drag on the canvas: every point of this frame inside the rectangle takes the class.")
        self.gui_class = gui.add_dropdown("Region class", ("ground",), initial_value="ground")
        self.gui_every = gui.add_checkbox("Every frame's ground", initial_value=False,
                                          hint="Show the ground of all frames from above, and draw on it.")
        self.gui_draw = gui.add_checkbox("Draw", initial_value=False, hint="While ticked, a click adds a vertex.")
        self.gui_prism = gui.add_checkbox("Every point between heights", initial_value=False,
                                          hint="Label every point inside the polygon from From to To above its "
                                               "ground (reviewed tracks' too), not only its ground points.")
        self.gui_low = gui.add_number("From (m above ground)", initial_value=0.2, step=0.1)
        self.gui_high = gui.add_number("To (m above ground)", initial_value=3.0, step=0.1)
        self.gui_depth = gui.add_vector2("Alt + drag depth (m)", (0.0, 0.0), min=(0.0, 0.0), step=0.5,
                                         hint="From, To: only the points at these distances from the camera "
                                              "(the boards, not the house seen through their gaps); 0, 0: all.")
        self.gui_status = gui.add_markdown("")
        self.gui_close = gui.add_button("Close & label", color="green", icon=viser.Icon.LASSO_POLYGON, disabled=True)
        self.gui_clear = gui.add_button("Clear", icon=viser.Icon.ERASER, disabled=True)
        self.gui_undo = gui.add_button("Undo last region", icon=viser.Icon.ARROW_BACK_UP, disabled=True)
        self.gui_regions = gui.add_markdown("")
        self.sequence_id: int | None = None  # whose regions and classes are loaded
        self.classes: RegionClasses | None = None
        self.regions: tuple[StoredRegion, ...] = ()
        self.draft: list[np.ndarray] = []  # (3,) world vertices: they stay put while the frame changes
        self._lock = threading.RLock()
        self._refreshing = threading.Lock()
        self._drawing = threading.Lock()
        self._on_canvas: set[str] = set()  # scene nodes this panel drew (a frame step removes only those)
        self.map_world: np.ndarray | None = None  # (M, 3) every frame's ground, world (ground_map)
        self.map_sequence: int | None = None  # whose it is
        self._map_frame: Any = None  # the /ground/map frame node
        self._map_drawn: tuple[int, list[tuple[int, str, bytes]]] | None = None  # what its colours show
        self._map_loading = False  # a read of another sequence's map is on its way
        self.gui_close.on_click(lambda _: self.close_and_label())
        self.gui_clear.on_click(lambda _: self.clear())
        self.gui_undo.on_click(lambda _: self.undo())
        self.gui_draw.on_update(lambda _: self._show_status())
        self.gui_every.on_update(lambda _: self.later(self.show_every_frame))
        scene.on_rect_select(modifier="alt")(self._on_rect)

    @property
    def drawing(self) -> bool:
        return bool(self.gui_draw.value)

    # ------------------------------------------------------------------ drawing
    def clicked(self, ray_origin: np.ndarray, ray_direction: np.ndarray) -> np.ndarray | None:
        """A click while drawing: the vertex (world) where its ray meets the ground, or None."""
        v = self.view()
        if v is None:
            self.notify("No frame", "Show a frame before drawing on its ground.", "yellow")
            return None
        points, ground = v.points, v.ground
        world = self._map_of(v.sequence_id)
        if world is not None:  # the clicks land on the ground of every frame
            points = world_to_lidar(world, v.T_world_lidar)
            ground = np.ones(len(points), bool)
        hit = click_on_ground(points, ground, np.asarray(ray_origin), np.asarray(ray_direction))
        if hit is None:
            self.notify("Not on the ground", "The click does not come down on this frame's ground; click lower.", "yellow")
            return None
        vertex = (v.T_world_lidar @ np.append(hit, 1.0))[:3]
        with self._lock:
            if self.sequence_id != v.sequence_id:
                self._load(v.sequence_id)
            if len(self.draft) >= MAX_VERTICES:
                self.notify("Too many vertices", f"A region has at most {MAX_VERTICES}; close it.", "yellow")
                return None
            self.draft.append(vertex)
        self.draw()
        return vertex

    def clear(self) -> None:
        with self._lock:
            self.draft = []
        self.draw()

    def close_and_label(self) -> dict[str, Any] | None:
        """Store the drawn polygon with the chosen class; the region as the service holds it."""
        with self._lock:
            seq, polygon = self.sequence_id, [[float(p[0]), float(p[1])] for p in self.draft]
        if seq is None or len(polygon) < 3:
            self.notify("Not a polygon yet", "Click at least three points on the ground.", "yellow")
            return None
        class_name, heights = str(self.gui_class.value), self.heights()
        try:
            region = self.api.create_ground_region(seq, class_name, polygon, heights)
        except ApiError as exc:
            self.notify("Region not stored", exc.detail, "red")
            return None
        with self._lock:
            self.draft = []
        what = "its ground points" if heights is None else "every point between its heights"
        self.notify("Region labelled", f"Region #{region['id']}: {what} are {class_name} in every frame.", "green")
        self.refresh()
        return region

    def _on_rect(self, event: viser.SceneRectSelectEvent) -> None:
        cam = event.client.camera
        clip_scene = clip_from_scene(np.asarray(cam.position), np.asarray(cam.wxyz), float(cam.fov), float(cam.aspect))
        self.label_in_view(rect_polygon_ndc(event.screen_min, event.screen_max), clip_scene)

    def label_in_view(self, polygon_ndc: np.ndarray, clip_from_lidar: np.ndarray) -> dict[str, Any] | None:
        """Store a lasso drawn in the frame shown ((K, 2) device coordinates of the camera whose
        (4, 4) matrix takes the frame's lidar points to clip space): every point of this frame
        inside it takes the chosen class. The region as the service holds it."""
        v = self.view()
        with self._lock:
            seq = self.sequence_id
        if v is None or v.frame_index is None or seq is None or seq != v.sequence_id:
            self.notify("No frame", "Show a frame before labelling its points.", "yellow")
            return None
        class_name = str(self.gui_class.value)
        clip_world = np.asarray(clip_from_lidar, np.float64) @ np.linalg.inv(v.T_world_lidar)
        near, far = (float(d) for d in self.gui_depth.value)
        if far > near:
            clip_world = with_depth_planes(clip_world, max(near, 0.01), far)
        try:
            region = self.api.create_ground_region(seq, class_name, np.asarray(polygon_ndc).tolist(),
                                                   frame_index=v.frame_index, clip_from_world=clip_world)
        except ApiError as exc:
            self.notify("Points not labelled", exc.detail, "red")
            return None
        self.notify("Points labelled", f"Region #{region['id']}: the points of frame {v.frame_index} inside the "
                                       f"rectangle are {class_name}.", "green")
        self.refresh()
        return region

    def heights(self) -> tuple[float, float] | None:
        """With *Every point between heights*: world z low, high (From and To above the median
        height of the draft's vertices, which sit on the ground); None otherwise."""
        with self._lock:
            if not self.gui_prism.value or not self.draft:
                return None
            ground = float(np.median(np.array(self.draft)[:, 2]))
        return ground + float(self.gui_low.value), ground + float(self.gui_high.value)

    def undo(self) -> dict[str, Any] | None:
        """Delete the newest region of the sequence (read now: another tab may have added one)."""
        seq = self.sequence_id
        if seq is None:
            return None
        try:
            newest = max(self.api.ground_regions(seq), key=lambda r: int(r["id"]), default=None)
            if newest is None:
                self.notify("Nothing to undo", "The sequence has no ground region.", "yellow")
                return None
            gone = self.api.delete_ground_region(int(newest["id"]))
        except ApiError as exc:
            self.notify("Undo refused", exc.detail, "yellow")
            self.refresh()
            return None
        self.notify("Region undone", f"Region #{gone['id']} ({gone['class_name']}) no longer labels the ground.", "blue")
        self.refresh()
        return gone

    # ------------------------------------------------------------------ what the service holds
    def _load(self, sequence_id: int) -> None:
        """Another sequence: its classes, no draft."""
        self.classes = RegionClasses.of(self.api, sequence_id)
        self.gui_class.options = self.classes.names
        if self.gui_class.value not in self.classes.names:
            self.gui_class.value = self.classes.names[0]
        self.sequence_id, self.draft, self.regions = sequence_id, [], ()

    def refresh(self) -> bool:
        """Re-read the regions of the frame's sequence; recolour the frame when they changed.
        Refreshes run one at a time (the feed, the tab's edits and its start all ask for one), so
        the list read last is the one kept."""
        v = self.view()
        if v is None:
            return False
        with self._refreshing:
            try:
                with self._lock:
                    if self.sequence_id != v.sequence_id:
                        self._load(v.sequence_id)
                regions = tuple(StoredRegion.from_public(r) for r in self.api.ground_regions(v.sequence_id))
            except ApiError as exc:
                self.gui_regions.content = f"Ground regions unavailable: {exc.detail}"
                return False
            with self._lock:
                changed = _keys(regions) != _keys(self.regions)
                self.regions = regions
        self._show_list()
        self.draw()
        if changed:
            self.recolour()
        return changed

    def _show_list(self) -> None:
        rows = [f"- #{r.id}: {r.class_name}, {len(r.polygon)} vertices"
                + ("" if r.heights is None else f", every point at z {r.heights[0]:.1f} to {r.heights[1]:.1f} m")
                + ("" if r.frame_index is None else f", frame {r.frame_index}" + (" (its view)" if r.view is not None else ""))
                for r in self.regions[-8:]]
        self.gui_regions.content = ("**Ground regions** (newest last; it wins where they overlap)  \n" + "\n".join(rows)
                                    if rows else "No ground region yet.")
        self.gui_undo.disabled = not self.regions

    def _show_status(self) -> None:
        n = len(self.draft)
        self.gui_close.disabled = n < 3
        self.gui_clear.disabled = n == 0
        hint = "click the ground to add vertices" if self.drawing else "tick Draw to add vertices"
        self.gui_status.content = f"{n} vertices; {hint}." if n or self.drawing else ""

    # ------------------------------------------------------------------ every frame's ground
    def _map_of(self, sequence_id: int) -> np.ndarray | None:
        """The map the clicks land on: shown, and of this sequence."""
        with self._lock:
            if self.gui_every.value and self.map_sequence == sequence_id:
                return self.map_world
        return None

    def show_every_frame(self) -> None:
        """Show or hide every frame's ground as the checkbox says; the first time for a sequence,
        read its frames (the viewer's frame cache) and look down on the route."""
        v = self.view()
        if not self.gui_every.value or v is None:
            self.draw()
            return
        if self.map_sequence != v.sequence_id:
            self.gui_status.content = "Reading the ground of every frame..."
            try:
                world = self.load_map(v.sequence_id)
            except ApiError as exc:
                self.notify("Cannot show every frame's ground", exc.detail, "red")
                return
            finally:
                self._map_loading = False
            with self._lock:
                self.map_world, self.map_sequence, self._map_drawn = world, v.sequence_id, None
        self.draw()
        with self._lock:
            world = self.map_world
        if world is not None and len(world):
            self.look_down(world_to_lidar(world, v.T_world_lidar))

    def _draw_map(self, v: GroundView, regions: tuple[StoredRegion, ...], classes: RegionClasses | None) -> None:
        """The map under a frame node at the world's pose in the frame shown; its points are sent
        again only when the regions (their colours) changed."""
        with self._lock:
            world = self.map_world if self.map_sequence == v.sequence_id else None
            stale = self.gui_every.value and self.map_sequence != v.sequence_id and not self._map_loading
            self._map_loading |= stale
        if stale:  # a track of another sequence came with the box ticked: read its ground
            self.later(self.show_every_frame)
        if not self.gui_every.value or world is None or not len(world):
            self._remove("/ground/map")
            self._map_frame, self._map_drawn = None, None
            return
        T_lidar_world = np.linalg.inv(v.T_world_lidar)
        pose = {"wxyz": tuple(matrix_wxyz(T_lidar_world[:3, :3])), "position": tuple(T_lidar_world[:3, 3])}
        if self._map_frame is None:
            self._on_canvas.add("/ground/map")
            self._map_frame = self.scene.add_frame("/ground/map", show_axes=False, **pose)
        else:
            self._map_frame.wxyz, self._map_frame.position = pose["wxyz"], pose["position"]
        key = (v.sequence_id, _keys(regions))
        if self._map_drawn == key:
            return
        colours = np.broadcast_to(MAP_GROUND, (len(world), 3))
        if classes is not None:
            colours = paint_regions(colours, world, np.ones(len(world), bool), regions, classes)
        self.scene.add_point_cloud("/ground/map/points", world.astype(np.float32), np.ascontiguousarray(colours),
                                   point_size=0.15, point_shading="flat", precision="float32")
        self._map_drawn = key

    # ------------------------------------------------------------------ the scene
    def paint(self, colours: np.ndarray, payload: FramePayload, keep: np.ndarray,
              tracks: dict[int, dict[str, Any]] | None, frame_index: int) -> np.ndarray:
        """(M, 3) colours of the background cloud (`keep` (M,) indices into the frame shown) with
        the points the stored regions label (ground_regions.labelable; `tracks`: the frame's
        TrackPublic by id, None in the track mode, where a region with heights colours only the
        points of no track) in their class colours, faded like the rest of the background.
        `colours` itself when none is."""
        v = self.view()
        with self._lock:
            regions, classes = self.regions, self.classes
            if v is None or self.sequence_id != v.sequence_id or classes is None or not regions:
                return colours
        assert payload.ground is not None
        eligible = labelable(payload.ground[keep], payload.track[keep], tracks, frame_index)
        any_point = None if tracks is not None else payload.track[keep] == 0
        return paint_regions(colours, to_world(payload.points[keep], v.T_world_lidar), eligible, regions, classes,
                             lambda c: fade(c, np.zeros(len(c), bool)), any_point, frame_index)

    def draw(self) -> None:
        """The draft polygon and the stored outlines, in the frame shown (call after a frame change,
        outside the client's atomic updates: draws from the GUI, the feed and the keys take turns,
        since viser cannot replace one scene node from two threads at once)."""
        with self._drawing:
            self._draw()

    def _draw(self) -> None:
        v = self.view()
        with self._lock:
            draft = np.array(self.draft, np.float64).reshape(-1, 3)
            regions, classes = self.regions, self.classes
            mine = v is not None and self.sequence_id == v.sequence_id
        self._show_status()
        if v is None or not mine:
            for name in ("/ground/draft", "/ground/nodes", "/ground/regions", "/ground/map"):
                self._remove(name)
            self._map_frame = self._map_drawn = None
            return
        self._draw_map(v, regions, classes)
        if len(draft):
            pts = world_to_lidar(draft, v.T_world_lidar)
            self._on_canvas.update(("/ground/nodes", "/ground/draft"))
            self.scene.add_point_cloud("/ground/nodes", pts, DRAFT, point_size=0.25, point_shape="circle",
                                       point_shading="flat", precision="float32")
            edges = _segments(pts, closed=len(pts) >= 3)
            colours = np.repeat(np.array([DRAFT] * (len(pts) - 1) + ([CLOSING] if len(pts) >= 3 else []),
                                         np.uint8).reshape(-1, 1, 3), 2, axis=1)
            if len(edges):
                self.scene.add_line_segments("/ground/draft", edges, colours, thickness=3.0, thickness_units="screen")
            else:
                self._remove("/ground/draft")
        else:
            self._remove("/ground/draft")
            self._remove("/ground/nodes")
        self._draw_regions(v, regions, classes)

    def _remove(self, name: str) -> None:
        if name in self._on_canvas:
            self._on_canvas.discard(name)
            self.scene.remove_by_name(name)

    def _draw_regions(self, v: GroundView, regions: tuple[StoredRegion, ...], classes: RegionClasses | None) -> None:
        z = ground_height(v.points, v.ground) if regions and classes is not None else None
        if not regions or classes is None or z is None:
            self._remove("/ground/regions")
            return
        world_z = float((v.T_world_lidar @ np.array([0.0, 0.0, z, 1.0]))[2])  # the frame's ground, in the world
        edges, colours = [], []
        for r in regions:
            if r.view is not None or (r.frame_index is not None and r.frame_index != v.frame_index):
                continue
            rgb = classes.colours.get(r.class_name, np.array([128, 128, 128], np.uint8))
            for h in (world_z,) if r.heights is None else r.heights:
                poly = world_to_lidar(np.column_stack([r.polygon, np.full(len(r.polygon), h)]), v.T_world_lidar)
                e = _segments(poly, closed=True)
                edges.append(e)
                colours.append(np.broadcast_to(rgb, (len(e), 2, 3)))
        if not edges:
            self._remove("/ground/regions")
            return
        self._on_canvas.add("/ground/regions")
        self.scene.add_line_segments("/ground/regions", np.concatenate(edges), np.concatenate(colours).astype(np.uint8),
                                     thickness=2.0, thickness_units="screen")
